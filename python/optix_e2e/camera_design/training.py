"""One training of a design run: Alg. 1 or vanilla to its last step on the task loss, with the
manufacturability guard after each lens step, the optics model's checks along the way, the
step's sensor-noise stream, and an atomic checkpoint every ``checkpoint_every`` steps from
which a killed run resumes on the same path (batches and noise are functions of (seed, step)).
Under torchrun each rank computes its slice of each batch and the gradients are averaged."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .. import parallel
from ..camera import Camera
from ..errors import InputError
from ..io import save_atomic, write_csv_atomic
from ..optics import DifferentiableOptics
from ..tasks import SensorFrame, TaskLoss, get_task, training_batch
from ..tasks.prefetch import Prefetched
from ..torchfile import DAMAGED_STATE_ERRORS, load_plain
from .config import DesignConfig
from .guard import Manufacturable, barrier_gradient, keep_manufacturable
from .hybrid import OpticsModeMismatch

LOSS_PARTS = ("l1", "lpips")  # the image-quality tasks' loss terms, in history.csv


def history_keys(parts: tuple[str, ...] = LOSS_PARTS) -> tuple[str, ...]:
    return ("step", "phase", "block", "loss", "prox", *parts, "cut", "barrier", "optics", "seconds")


def _save_state(path: Path, camera: Camera, opt, wall_s: float, history: list, monitor=None) -> None:
    save_atomic(
        {
            "format": "optix-design-state/1",
            "camera": camera.state_dict(),
            "optimizer": opt.state_dict(),
            "wall_s": wall_s,
            "history": history,
            "monitor": monitor.state_dict() if monitor is not None else None,
        },
        path,
    )


def _load_state(path: Path, camera: Camera, opt, monitor=None) -> tuple[float, list]:
    st = load_plain(path, "design checkpoint")
    if not isinstance(st, dict) or st.get("format") != "optix-design-state/1":
        raise InputError(f"{path}: not a design checkpoint (format optix-design-state/1)")
    try:
        _check_schedule(path, st, opt)
        camera.load_state_dict(st["camera"])
        opt.load_state_dict(st["optimizer"])
        wall_s, history = float(st["wall_s"]), list(st["history"])
        if not 0 <= opt.t <= opt.total_steps:
            raise InputError(f"step {opt.t} outside this run's 0..{opt.total_steps}")
        if not (math.isfinite(wall_s) and wall_s >= 0):
            raise InputError(f"wall_s {wall_s}")
        if monitor is not None and st.get("monitor") is not None:
            monitor.load_state_dict(st["monitor"])
    except (OpticsModeMismatch, OtherSchedule):
        raise  # its own message: the run's optics model or schedule differs, the checkpoint is fine
    except DAMAGED_STATE_ERRORS as err:
        raise InputError(
            f"{path}: damaged design checkpoint ({type(err).__name__}: {' '.join(str(err).split())}); "
            f"remove it to restart that training"
        ) from None
    return wall_s, history


class OtherSchedule(InputError):
    """A checkpoint whose steps updated other blocks than this run's schedule would have."""


def _check_schedule(path: Path, st: dict, opt) -> None:
    """The checkpoint's steps were taken under this run's schedule: each recorded step updated
    the block this optimizer's schedule updates at that step, and there are no more of them
    than the schedule has. A checkpoint of another schedule (the nominal baseline's before it
    got the end-to-end camera's updates per block, 2026-11-27, issue 34) is refused with an
    error saying so, never resumed on a schedule it was not made with."""
    ost, history = st.get("optimizer"), st.get("history")
    t = ost.get("t") if isinstance(ost, dict) else None
    if not (isinstance(t, int) and isinstance(history, list) and len(history) == t):
        return  # damaged: _load_state says so
    done = [h.get("block") if isinstance(h, dict) else None for h in history]
    want = [opt.block_at(i) for i in range(min(t, opt.total_steps))]
    first = next((i for i, (d, w) in enumerate(zip(done, want)) if d != w), None)
    what = None
    if ost.get("kind") != opt.kind:
        what = f"by the {ost.get('kind')!r} optimizer, this run's is {opt.kind!r}"
    elif first is not None:
        what = f"step {first + 1} updated {done[first]!r} where this run's schedule updates {want[first]!r}"
    elif t > opt.total_steps:
        what = f"it is at step {t}, this run's schedule has {opt.total_steps}"
    if what is not None:
        raise OtherSchedule(
            f"{path}: made under another schedule ({what}; the nominal baseline gets as many updates per "
            f"processing block as the end-to-end camera since 2026-11-27); remove it to train that camera "
            f"again, or use another --out"
        )


#: whether a design run on the CPU makes its next batch beside the step (the step's own threads
#: use the cores; measured in docs/gpu.md): off; on any other device, on
PREFETCH_ON_CPU = False


def prefetch_batches(device) -> bool:
    return torch.device(device).type != "cpu" or PREFETCH_ON_CPU


def noise_generator(seed: int, t: int, ranks: parallel.Ranks = parallel.Ranks()) -> torch.Generator:
    """Step t's sensor-noise stream (stream tag 4); under torchrun each rank draws its own."""
    key = [4, int(seed), int(t)] + ([ranks.rank, ranks.world] if ranks.distributed else [])
    return torch.Generator().manual_seed(int(np.random.SeedSequence(key).generate_state(1)[0]))


def train(
    cfg: DesignConfig,
    camera: Camera,
    opt,
    out: Path,
    name: str,
    *,
    progress: bool = True,
    writer=None,
    frame: SensorFrame = SensorFrame(),
    folder=None,
    corpus=None,
    on_step=None,
    log=None,
    loss_at=None,
    parts: tuple[str, ...] = LOSS_PARTS,
    monitor=None,
    ranks: parallel.Ranks = parallel.Ranks(),
    lens_scale: torch.Tensor | None = None,
) -> dict:
    """Run ``opt`` to its last step on the task loss, checkpointing into out/{name}_state.pt.
    ``loss_at(t, generator)`` -> (loss, {part: value}) is step t's loss (default: the
    image-quality task's on ``training_batch``); ``parts`` name the values it reports.
    ``monitor``: an camera_design.hybrid.OpticsMonitor checking the optics model along the way
    (before the first step, every ``check_every`` steps and after the last).
    ``ranks``: under torchrun, each rank computes its slice of every batch (a ``loss_at`` given
    here must do so too), the gradients are averaged before each step, rank 0 writes.
    ``lens_scale`` [P]: factors on each lens step's change of ``optics.u``, per parameter, before
    the guard sees the step (``lens_steps = "range"``: DifferentiableOptics.range_step_scale of
    the run's start, so a resumed run scales as it began)."""
    task = get_task(cfg.task)
    state_path = out / f"{name}_state.pt"
    wall_s, history = 0.0, []
    if state_path.is_file():
        wall_s, history = _load_state(state_path, camera, opt, monitor)
        if log is not None and ranks.is_main:
            log(f"{name}: resuming at step {opt.t} of {opt.total_steps} ({state_path.name})")
    ran = opt.t < opt.total_steps
    if ranks.distributed:
        parallel.broadcast_params(camera.parameters(), ranks)  # one starting point, whatever each rank read
        opt.reduce = lambda params, loss, info: parallel.average_step(ranks, params, loss, info)
        progress = progress and ranks.is_main
    stream = None
    if loss_at is None:
        dev = camera.device  # a batch is drawn on the CPU (seeded) and goes to the camera once
        loss_mod = TaskLoss(task).to(dev)
        part = parallel.batch_slice(cfg.batch, ranks)
        # batch t + 1 made while step t runs, where the step is not the CPU's (tasks/prefetch.py)
        stream = Prefetched(
            lambda t: training_batch(
                cfg.seed,
                t,
                cfg.batch,
                cfg.crop,
                m,
                (task.level_min, task.level_max),
                frame,
                folder,
                positions=cfg.train_positions,
                corpus=corpus,
            ),
            ahead=prefetch_batches(dev),
            last=opt.total_steps - 1,
        )

        def loss_at(t, gen):
            batch = stream(t)
            out_img, _ = camera(batch.scene[part].to(dev), batch.offset_px, gen)
            return loss_mod(out_img, batch.target[part].to(dev))

    optics = camera.optics if isinstance(camera.optics, DifferentiableOptics) else None
    guard = Manufacturable(optics.surrogate.manifest) if optics is not None and optics.surrogate.manifest else None
    if guard is not None and cfg.guard == "barrier":

        def steer(params) -> dict:
            """The barrier's gradient joins the lens's before Adam steps (guard.barrier_gradient)."""
            if not any(p is optics.u for p in params):
                return {}
            grad, value = barrier_gradient(optics, guard, cfg.guard_band, cfg.guard_weight)
            if value:
                with torch.no_grad():
                    optics.u.grad = grad.to(optics.u) if optics.u.grad is None else optics.u.grad + grad.to(optics.u)
            return {"barrier": value}

        opt.before_step = steer
    camera.train()
    m = camera.margin
    t_start = time.perf_counter()
    bar = tqdm(
        total=opt.total_steps,
        initial=opt.t,
        desc=f"{name} ({opt.kind})",
        unit="step",
        disable=not progress,
        leave=False,
    )
    if monitor is not None and opt.t == 0 and not monitor.checks:
        monitor.check(0)
    try:
        while opt.t < opt.total_steps:
            t = opt.t
            gen = noise_generator(cfg.seed, t, ranks)

            def loss_fn():
                return loss_at(t, gen)

            t0 = time.perf_counter()
            u_prev = optics.u.detach().clone() if optics is not None else None
            backend = optics.backend if optics is not None else "fixed"
            info = opt.step(loss_fn)
            if lens_scale is not None and optics is not None and info["block"] in ("optics", "all"):
                with torch.no_grad():  # per-parameter step sizes (Adam's step is one lr for the whole tensor u)
                    optics.u.copy_(u_prev + lens_scale.to(optics.u) * (optics.u - u_prev))
            hint = "lower the learning rates (lr_optics, lr_isp_net, lr_isp_params, lr_detector) in another --out"
            parallel.stop_if_diverged(opt.t, state_path, hint, loss=info["loss"])
            info["optics"] = backend
            # the paper enforces its limits on every lens: a step that breaks one is cut back
            info["cut"] = int(
                guard is not None and info["block"] in ("optics", "all") and keep_manufacturable(optics, u_prev, guard)
            )
            info["seconds"] = time.perf_counter() - t0
            info.setdefault("barrier", 0.0)  # the guard's barrier term (guard = barrier), not in the loss
            row = {k: info[k] for k in history_keys(parts)}
            if optics is not None and info["block"] in ("optics", "all"):
                # where this step left the lens (lens_path.csv)
                row["lens"] = [float(v) for v in optics.values().detach()]
            history.append(row)
            if writer is not None:
                for k in ("loss", *parts):
                    writer.add_scalar(f"{name}/{k}", info[k], info["step"])
                if info["prox"]:
                    writer.add_scalar(f"{name}/prox", info["prox"], info["step"])
                if info.get("barrier"):
                    writer.add_scalar(f"{name}/barrier", info["barrier"], info["step"])
            if monitor is not None and monitor.due(opt.t, opt.total_steps):
                monitor.check(opt.t, final=opt.t == opt.total_steps)
            if on_step is not None:
                on_step(info, camera)
            bar.update(1)
            bar.set_postfix(loss=f"{info['loss']:.4f}", block=info["block"])
            if opt.t % cfg.checkpoint_every == 0 or opt.t == opt.total_steps:
                parallel.stop_if_diverged(opt.t, state_path, hint, camera=camera)  # every rank: all stop together
            if ranks.is_main and (opt.t % cfg.checkpoint_every == 0 or opt.t == opt.total_steps):
                _save_state(state_path, camera, opt, wall_s + time.perf_counter() - t_start, history, monitor)
    finally:
        if stream is not None:
            stream.close()  # the thread ends with the run, a failed step included
    bar.close()
    wall = wall_s + (time.perf_counter() - t_start if ran else 0.0)
    camera.eval()
    return {
        "steps": opt.t,
        "wall_s": wall,
        "final_loss": history[-1]["loss"] if history else math.nan,
        "cut_steps": int(sum(h.get("cut", 0) for h in history)),
        "lens_steps": int(sum(h.get("block") in ("optics", "all") for h in history)) if optics is not None else 0,
        "guard": cfg.guard if guard is not None else None,
        "barrier_steps": int(sum(bool(h.get("barrier")) for h in history)),
        # the updates each block received (its Adam's step count, across resumes)
        "updates": opt.updates(),
        "history": history,
    }


def write_lens_path(path: Path, history: list[dict], names: list[str], start) -> None:
    """The lens after each of a training's lens steps (its parameters in their units, step 0
    the start), one row per step: what the run did to the lens, step by step."""
    rows = [[0, "start", 0, *[float(v) for v in start]]]
    rows += [[h["step"], h["block"], h.get("cut", 0), *h["lens"]] for h in history if "lens" in h]
    write_csv_atomic(path, rows, header=["step", "block", "cut", *names])


def lens_travel(names: list[str], lo, hi, start, history: list[dict]) -> dict:
    """How far the lens moved, as fractions of each parameter's range: ``final`` (final minus
    start, signed) and ``farthest`` (the largest distance from the start along the way), per
    parameter and the largest over them."""
    lo, hi, start = (np.asarray(x, float) for x in (lo, hi, start))
    path = np.array([h["lens"] for h in history if "lens" in h] or [start], float)
    span = np.where(hi > lo, hi - lo, 1.0)
    final = (path[-1] - start) / span
    farthest = np.abs(path - start).max(axis=0) / span
    return {
        "lens_steps_recorded": int(sum("lens" in h for h in history)),
        "largest_final": float(np.abs(final).max()),
        "largest_farthest": float(farthest.max()),
        "per_parameter": {
            n: {"start": float(s), "final": float(p), "final_fraction": float(f), "farthest_fraction": float(m)}
            for n, s, p, f, m in zip(names, start, path[-1], final, farthest)
        },
    }


def write_history(path: Path, runs: dict, parts: tuple[str, ...] = LOSS_PARTS) -> None:
    keys = history_keys(parts)
    write_csv_atomic(
        path, ([run] + [h.get(k, "") for k in keys] for run, hist in runs.items() for h in hist), header=["run", *keys]
    )
