#!/usr/bin/env python3
"""The GPU check of issue 36: what each torch stage costs on CUDA and on the CPU, in one call.

    python benches/gpu.py --out DIR [--quick | --smoke] [--steps N] [--devices cuda,cpu]
                          [--precision fp32,bf16] [--part-seconds S]

For each device (CUDA when torch sees a GPU, and always the CPU) it times, after a warm-up:

1. ``design``: one training step of ``optix design iq-software`` at the quick budget's shapes
   (crop 128, batch 4, the paper-triplet-e2e surrogate, every block learning: the fine-tuning
   phase, the most expensive step), split by stage: batch (the seeded scenes drawn on the CPU
   and moved), optics (the surrogate's PSFs), render (overlap-add), sensor (EMVA with noise),
   ISP (the software ISP net), loss (L1 + LPIPS), backward, optimizer (Adam). Surrogate optics:
   no Rust engine in this loop.
2. ``design_exact``: the same step with the engine's exact optics (PSFs and their central-
   difference Jacobian on the CPU, whatever the device; the design run's default optics),
   fewer steps: it is the engine's time, not torch's.
3. ``surrogate``: training steps of the optics surrogate (the bundled paper-triplet-e2e's
   network, Eq. 8's loss, gradient clipping, Adam) at ``optix surrogate train``'s batch of 256
   (design, field) samples, on a SYNTHETIC batch of the right shapes (random parameters in the
   space, random unit-sum PSFs as targets): a throughput figure, not a training.
4. ``detector``: training steps of the detector (FCOS on TinyBackbone, AdamW) at the design
   run's crop 192 x 288, batch 8 (``optix detect train``'s), on SYNTHETIC images with random
   boxes (3 to 8 per image).

Each timing brackets its stage with ``torch.cuda.synchronize`` on CUDA (``perf_counter``), the
median over the timed steps is reported; on CUDA each part's peak memory
(``torch.cuda.max_memory_allocated``, the peak reset before the part). With ``--precision
fp32,bf16`` (or fp16) each part but the exact step is also timed on the GPU with the networks
under that autocast (the precision switch of ``optix design --precision``; optics, sensor and
loss stay float32); the CPU beside a GPU is timed at fp32 only (the ratios' denominator), the
CPU alone (``--devices cpu``) at every precision asked for.

Writes DIR/gpu.json (the machine: torch and CUDA versions, GPU name, CPU threads; per device and
precision the parts' figures; the CPU / GPU ratios) and prints one line per figure. Each part
stops its timed loop after ``--part-seconds`` (default 60) so the whole call stays within its
time whatever the machine: the JSON says how many steps each figure is the median of.

It measures; it asserts nothing. ``--quick``: 1 warm-up and 2 timed steps per part (about a
minute on a loaded 2-core CPU); ``--smoke``: the smoke budget's shapes and one step, for the
test that checks the JSON's structure.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

DESIGN_STAGES = ("batch", "optics", "render", "sensor", "isp", "loss", "backward", "optimizer")
FORMAT = "optix-gpu-bench/1"


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def _reset_peak(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)


def _peak_mib(dev: torch.device) -> float | None:
    return round(torch.cuda.max_memory_allocated(dev) / 2**20, 1) if dev.type == "cuda" else None


class Plan:
    """How many steps each part runs: ``warmup`` untimed, then up to ``steps`` timed (fewer if
    ``part_seconds`` run out first; at least one)."""

    def __init__(self, warmup: int, steps: int, exact_steps: int, part_seconds: float, smoke: bool):
        self.warmup, self.steps, self.exact_steps = warmup, steps, exact_steps
        self.part_seconds, self.smoke = part_seconds, smoke

    def loop(self, n: int | None = None):
        """Yields (i, timed) for the warm-up then the timed steps, within the part's seconds."""
        n = self.steps if n is None else n
        t0 = time.perf_counter()
        for i in range(self.warmup + n):
            timed = i >= self.warmup
            if timed and i > self.warmup and time.perf_counter() - t0 > self.part_seconds:
                return
            yield i, timed


@contextlib.contextmanager
def _step_timer(dev: torch.device, times: dict[str, list[float]], timed: bool):
    """Times the body as one step, the device synchronized on both sides, into times["step"]
    where ``timed`` (a warm-up step runs the same way, untimed)."""
    _sync(dev)
    t0 = time.perf_counter()
    yield
    _sync(dev)
    if timed:
        times["step"].append(time.perf_counter() - t0)


def _median_ms(times: dict[str, list[float]]) -> dict[str, float]:
    return {k: round(1e3 * statistics.median(v), 2) for k, v in times.items() if v}


# -- 1, 2: a design training step ----------------------------------------------------------------


def design_step(dev: torch.device, plan: Plan, precision: str = "fp32", exact: bool = False) -> dict:
    from optix_e2e.camera_design.build import build_camera, load_surrogate
    from optix_e2e.camera_design.training import noise_generator
    from optix_e2e.optics.render import render
    from optix_e2e.tasks import SensorFrame, TaskLoss, get_task, training_batch

    budget = "smoke" if plan.smoke else "quick"
    cfg = _design_config(budget, dev, precision)
    task, frame = get_task(cfg.task), SensorFrame()
    sur = load_surrogate(cfg.surrogate).to(dev)
    cam = build_camera(cfg, sur, frame=frame, device=dev)
    _apply_precision(cam, cfg, dev)
    if exact:
        cam.optics.backend = "exact"
    cam.train()
    loss_mod = TaskLoss(task).to(dev)
    params = [p for ps in cam.blocks().values() for p in ps]
    for p in params:
        p.requires_grad_(True)
    opt = torch.optim.Adam(params, lr=1e-6)  # tiny: the camera hardly moves while it is timed
    scaler = _scaler(dev, precision)
    m = cam.margin
    fields = cam.optics.fields if cam.optics.render_fields is None else cam.optics.render_fields
    times: dict[str, list[float]] = {k: [] for k in (*DESIGN_STAGES, "step")}
    host: list[float] = []  # per step: the share in work on the CPU whatever the device
    engine = cam.optics.exact if exact else None
    _reset_peak(dev)
    n = 0
    for t, timed in plan.loop(plan.exact_steps if exact else None):
        c = [time.perf_counter()]
        e = [engine.seconds] if engine is not None else []

        def lap():
            _sync(dev)
            c.append(time.perf_counter())

        b = training_batch(
            cfg.seed, t, cfg.batch, cfg.crop, m, (task.level_min, task.level_max), frame, positions=cfg.train_positions
        )
        scene, target = b.scene.to(dev), b.target.to(dev)
        opt.zero_grad(set_to_none=True)
        lap()
        psf, vig = cam.optics.psfs()
        lap()
        if engine is not None:
            e.append(engine.seconds)
        img = render(
            scene,
            psf,
            fields,
            vig,
            patch=cfg.patch,
            full_field_px=frame.full_field_px,
            offset_px=b.offset_px,
        )[..., m:-m, m:-m]
        lap()
        raw = cam.sensor(img, noise_generator(cfg.seed, t), f_number=cam.optics.f_number())
        lap()
        out = cam.isp(raw, b.offset_px, frame.full_field_px)
        lap()
        loss, _ = loss_mod(out, target)
        lap()
        (scaler.scale(loss) if scaler is not None else loss).backward()
        lap()
        if engine is not None:
            e.append(engine.seconds)  # the engine's gradient inside the backward pass
        if scaler is not None:
            scaler.step(opt)
            scaler.update()
        else:
            opt.step()
        lap()
        if timed:
            n += 1
            for k, (x, y) in zip(DESIGN_STAGES, zip(c, c[1:])):
                times[k].append(y - x)
            times["step"].append(c[-1] - c[0])
            # the scenes are drawn on the CPU; the exact optics' forward stage and the engine's
            # time in the backward pass run there too
            on_host = (c[1] - c[0]) + ((c[2] - c[1]) + (e[2] - e[1]) if engine is not None else 0.0)
            host.append(on_host / (c[-1] - c[0]))
    med = _median_ms(times)
    return {
        "what": f"optix design iq-software, {budget} budget's shapes, {'exact' if exact else 'surrogate'} optics",
        "crop": cfg.crop,
        "batch": cfg.batch,
        "psf_size": int(cam.optics.psf_size),
        "steps": n,
        "median_ms": med,
        "steps_per_s": round(1e3 / med["step"], 3),
        # on a GPU, the share of the step it waits for the CPU (the median over the steps)
        "host_fraction": round(float(sorted(host)[len(host) // 2]), 4) if host else None,
        "peak_mib": _peak_mib(dev),
    }


def _design_config(budget: str, dev: torch.device, precision: str):
    from optix_e2e.camera_design.config import DesignConfig, make_config

    extra = {"precision": precision} if "precision" in DesignConfig.__dataclass_fields__ else {}
    return make_config(budget, task="iq-software", optics="surrogate", device=str(dev), **extra)


def _apply_precision(cam, cfg, dev) -> None:
    """The design run's precision switch on the camera's networks."""
    from optix_e2e.precision import apply_precision, resolve_precision

    apply_precision(cam, resolve_precision(cfg.precision, dev))


def _scaler(dev: torch.device, precision: str):
    return torch.amp.GradScaler(dev.type) if precision == "fp16" else None


def _dtype(precision: str):
    return {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}[precision]


# -- 3: surrogate training -------------------------------------------------------------------


def surrogate_train(dev: torch.device, plan: Plan, precision: str = "fp32") -> dict:
    from optix_e2e.surrogate.checkpoint import OpticsSurrogate
    from optix_e2e.surrogate.loss import optics_loss_terms
    from optix_e2e.surrogate.train import TrainConfig

    tc = TrainConfig()
    model = OpticsSurrogate.load("paper-triplet-e2e").to(dev).train()
    net = model.net
    batch = 16 if plan.smoke else tc.batch
    mc = net.cfg
    g = torch.Generator().manual_seed(0)
    # the ranges as float32 on the CPU, where the synthetic batches are drawn (the model is on dev)
    lo, hi = (x.detach().to("cpu", torch.float32) for x in (model.param_min, model.param_max))
    batches = []
    for _ in range(4):  # a few synthetic batches, made on the CPU, cycled
        params = lo + (hi - lo) * torch.rand(batch, mc.n_params, generator=g)
        field = torch.rand(batch, generator=g)
        psf = torch.rand(batch, mc.channels, mc.psf_size, mc.psf_size, generator=g) ** 4
        psf = psf / psf.sum((-2, -1), keepdim=True)
        vig = 0.5 + 0.5 * torch.rand(batch, mc.channels, generator=g)
        batches.append((params, field, psf, vig))
    opt = torch.optim.Adam(net.parameters(), lr=tc.lr)
    dtype, scaler = _dtype(precision), _scaler(dev, precision)
    times: dict[str, list[float]] = {"step": []}
    _reset_peak(dev)
    for i, timed in plan.loop():
        params, field, psf_t, vig_t = (x.to(dev) for x in batches[i % len(batches)])
        with _step_timer(dev, times, timed):
            with torch.autocast(dev.type, dtype=dtype, enabled=dtype is not None):
                psf, vig = net(model.normalize(params), field)
            terms = optics_loss_terms(psf.float(), vig.float(), psf_t, vig_t)
            loss = tc.weights.total(terms)
            _optimizer_step(opt, loss, scaler, net.parameters(), tc.clip_grad)
    med = _median_ms(times)
    return {
        "what": "optix surrogate train's step (paper-triplet-e2e's network, Eq. 8, clip, Adam), synthetic batch",
        "batch": batch,
        "psf_size": int(mc.psf_size),
        "steps": len(times["step"]),
        "median_ms": med,
        "steps_per_s": round(1e3 / med["step"], 3),
        "peak_mib": _peak_mib(dev),
    }


def _optimizer_step(opt, loss, scaler, clip_params=None, clip: float | None = None) -> None:
    """Backward and one optimizer step, through the fp16 gradient scaler where there is one
    (unscaled before clipping ``clip_params`` to ``clip``)."""
    opt.zero_grad(set_to_none=True)
    (scaler.scale(loss) if scaler is not None else loss).backward()
    if clip_params is not None:
        if scaler is not None:
            scaler.unscale_(opt)
        torch.nn.utils.clip_grad_norm_(clip_params, clip)
    if scaler is not None:
        scaler.step(opt)
        scaler.update()
    else:
        opt.step()


# -- 4: detector training ------------------------------------------------------------------------


def detector_train(dev: torch.device, plan: Plan, precision: str = "fp32") -> dict:
    from optix_e2e.tasks.detector import make_detector

    h, w, batch = (64, 96, 2) if plan.smoke else (192, 288, 8)
    torch.manual_seed(0)
    model = make_detector(32, 64, (h, w)).to(dev).train()
    from optix_e2e.precision import apply_precision

    apply_precision(model, _dtype(precision))
    g = torch.Generator().manual_seed(0)
    batches = []
    for _ in range(4):
        xs, ts = [], []
        for _ in range(batch):
            k = int(torch.randint(3, 9, (1,), generator=g))
            wh = 8 + 56 * torch.rand(k, 2, generator=g)
            xy = torch.rand(k, 2, generator=g) * (torch.tensor([w, h]) - wh)
            xs.append(torch.rand(3, h, w, generator=g))
            ts.append({"boxes": torch.cat([xy, xy + wh], 1), "labels": torch.randint(1, 5, (k,), generator=g)})
        batches.append((xs, ts))
    opt = torch.optim.AdamW(model.parameters(), 2e-3, weight_decay=1e-4)
    scaler = _scaler(dev, precision)
    times: dict[str, list[float]] = {"step": []}
    _reset_peak(dev)
    for i, timed in plan.loop():
        xs, ts = batches[i % len(batches)]
        with _step_timer(dev, times, timed):
            xs, ts = [x.to(dev) for x in xs], [{k: v.to(dev) for k, v in t.items()} for t in ts]
            loss = sum(model(xs, ts).values())
            _optimizer_step(opt, loss, scaler)
    med = _median_ms(times)
    return {
        "what": "optix detect train's step (FCOS on TinyBackbone, AdamW), synthetic images and boxes",
        "image": [h, w],
        "batch": batch,
        "steps": len(times["step"]),
        "median_ms": med,
        "steps_per_s": round(1e3 / med["step"], 3),
        "peak_mib": _peak_mib(dev),
    }


PARTS = {
    "design": lambda dev, plan, prec: design_step(dev, plan, prec),
    "design_exact": lambda dev, plan, prec: design_step(dev, plan, prec, exact=True),
    "surrogate": surrogate_train,
    "detector": detector_train,
}
#: the parts timed at a lower precision too (the exact step's cost is the engine's)
NETWORK_PARTS = ("design", "surrogate", "detector")


def machine() -> dict:
    cuda = torch.cuda.is_available()
    return {
        "torch": torch.__version__,
        "cuda": torch.version.cuda,
        "gpu": torch.cuda.get_device_name(0) if cuda else None,
        "gpu_count": torch.cuda.device_count() if cuda else 0,
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
    }


def lines(res: dict) -> list[str]:
    """One line per figure."""
    out = []
    for dev, by_prec in res["devices"].items():
        for prec, parts in by_prec.items():
            for part, r in parts.items():
                if "error" in r:
                    out.append(f"{dev} {prec} {part}: error {r['error']}")
                    continue
                for stage, ms in r["median_ms"].items():
                    out.append(f"{dev} {prec} {part} {stage} {ms} ms (median of {r['steps']})")
                out.append(f"{dev} {prec} {part} {r['steps_per_s']} steps/s")
                if r.get("host_fraction") is not None:
                    out.append(
                        f"{dev} {prec} {part} on the CPU whatever the device: {r['host_fraction']:.1%} of the step"
                    )
                if r["peak_mib"] is not None:
                    out.append(f"{dev} {prec} {part} peak memory {r['peak_mib']} MiB")
    for key, x in res["ratios"].items():
        out.append(f"ratio {key} {x}x")
    return out


def ratios(devices: dict) -> dict:
    """CPU time / CUDA time per part and stage (fp32 CPU against each CUDA precision)."""
    cpu = devices.get("cpu", {}).get("fp32", {})
    out = {}
    for dev, by_prec in devices.items():
        if dev == "cpu":
            continue
        for prec, parts in by_prec.items():
            for part, r in parts.items():
                base = cpu.get(part)
                if not base or "error" in base or "error" in r:
                    continue
                for stage, ms in r["median_ms"].items():
                    if stage in base["median_ms"] and ms > 0:
                        out[f"{part} {stage} cpu/{dev}-{prec}"] = round(base["median_ms"][stage] / ms, 2)
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder for gpu.json")
    ap.add_argument("--quick", action="store_true", help="1 warm-up and 2 timed steps per part")
    ap.add_argument("--smoke", action="store_true", help="smoke shapes, one step per part (tests)")
    ap.add_argument("--steps", type=int, default=None, help="timed steps per part (default 20; exact optics 3)")
    ap.add_argument("--warmup", type=int, default=None, help="untimed steps first (default 3)")
    ap.add_argument("--devices", default=None, help="comma-separated (default: cuda when present, and cpu)")
    ap.add_argument("--precision", default="fp32", help="comma-separated: fp32, bf16, fp16 (default fp32)")
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {', '.join(PARTS)}")
    ap.add_argument("--part-seconds", type=float, default=60.0, help="stop a part's timed loop after this")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    a = ap.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    warmup = a.warmup if a.warmup is not None else (0 if a.smoke else 1 if a.quick else 3)
    steps = a.steps if a.steps is not None else (1 if a.smoke else 2 if a.quick else 20)
    plan = Plan(warmup, steps, max(1, min(steps, 3)), a.part_seconds, a.smoke)
    devices = a.devices.split(",") if a.devices else (["cuda"] if torch.cuda.is_available() else []) + ["cpu"]
    precisions = a.precision.split(",")
    parts = a.parts.split(",")
    for p in parts:
        if p not in PARTS:
            ap.error(f"unknown part {p!r}")
    for p in precisions:
        if p not in ("fp32", "bf16", "fp16"):
            ap.error(f"unknown precision {p!r}")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    res = {
        "format": FORMAT,
        "machine": machine(),
        "settings": {
            "warmup": warmup,
            "steps": steps,
            "exact_steps": plan.exact_steps,
            "part_seconds": a.part_seconds,
            "smoke": a.smoke,
            "precision": precisions,
            "parts": parts,
        },
        "devices": {},
    }
    for name in devices:
        dev = torch.device(name)
        if dev.type == "cuda" and dev.index is None:
            dev = torch.device("cuda", 0)
        res["devices"][name] = {}
        for prec in precisions:
            res["devices"][name][prec] = figures = {}
            for part in parts:
                if prec != "fp32" and (part not in NETWORK_PARTS or (dev.type == "cpu" and len(devices) > 1)):
                    continue  # the CPU beside a GPU: fp32 only, the ratios' denominator (module doc)
                try:
                    figures[part] = PARTS[part](dev, plan, prec)
                except Exception as err:  # a part that cannot run here (fp16 on a CPU without it) is recorded
                    figures[part] = {"error": f"{type(err).__name__}: {err}"}
                print(*[ln for ln in lines({"devices": {name: {prec: {part: figures[part]}}}, "ratios": {}})], sep="\n")
                sys.stdout.flush()
                # written after each part: a call cut off at its time limit still leaves the parts done
                (out / "gpu.json").write_text(json.dumps(res, indent=2))
    res["ratios"] = ratios(res["devices"])
    for key, x in res["ratios"].items():
        print(f"ratio {key} {x}x")
    res["wall_s"] = round(time.perf_counter() - t0, 1)
    (out / "gpu.json").write_text(json.dumps(res, indent=2))
    print(f"wall {res['wall_s']} s; {out / 'gpu.json'}")
    return res


if __name__ == "__main__":
    main()
