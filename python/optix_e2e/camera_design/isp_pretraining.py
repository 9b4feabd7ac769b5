"""Pre-training of the software ISP on what the camera will see (paper Sec. 5.2: "we first
pre-train the software ISPs on synthetic training data"), resumable, with a validation curve.

A training sample is made the way a design run makes one, with the lens drawn at random:

* a scene from the natural training mix (scenes/natural.py; with ``photos``, corpora of real
  photographs prepared by ``optix scenes photos prepare``: their crops at native scale the
  majority, scenes/natural.py's PHOTO_MIX), lit at a white level
  log-uniform in [0.35, 1] of the calibrated white, under the neutral illuminant the camera is
  calibrated for (docs/e2e.md, "Illuminant");
* a lens: the perfect one (a delta PSF, no vignetting), the space's nominal, or a design drawn
  uniformly from the space, through the optics surrogate (its PSFs and relative illumination
  at the K fields, rendered with the same overlap-add renderer as the tasks);
* a crop position uniform over the 1920 x 1200 frame (even rows and columns: the frame's CFA
  phase), so the network sees every field;
* the IMX249 at the tasks' light: normal, or low light (exposure / 100, gain x 100);
* the target: the ideal rendering of the scene at its level (the tasks' target).

Samples come in pools made ahead of the steps that use them (a pool is a function of the
seed and its index alone); the loss is L1 in sRGB (plus ``lpips_weight`` x LPIPS, the design
runs' fine-tuning loss with weight 1), Adam with cosine decay over the steps or the wall-time
budget, whichever ends first. With photos, validation draws from the corpora's ``val`` split. ``state.pt`` (weights, optimizer, step, curve)
is written every ``checkpoint_every`` steps and atomically, so the same command continues
after any stop, on the same curve.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .. import color
from ..camera import calibrated_preset
from ..dataset.manifest import space_and_base
from ..device import resolve_device
from ..errors import InputError
from ..io import save_atomic, tensorboard_writer, write_record_atomic, write_text_atomic
from ..isp.software import SoftwareISP
from ..isp.train import cosine_lr
from ..optics.render import render
from ..parallel import set_threads, stop_if_diverged
from ..precision import apply_precision, grad_scaler, resolve_precision, scaled_backward, scaled_step
from ..scenes.natural import natural_scene
from ..sensor import simulate_raw
from ..tasks.samples import SensorFrame
from ..torchfile import load_plain
from .build import base_lens_f_number, load_surrogate, nominal_field_heights

FORMAT = "optix-isp-pretraining/1"
LENS_KINDS = ("perfect", "nominal", "space")


@dataclass(frozen=True)
class PretrainConfig:
    steps: int = 200_000
    minutes: float = 0.0  # stop after this wall time in this call (0: no limit)
    batch: int = 8
    crop: int = 128  # sensor pixels per side
    pool: int = 256  # samples per pool
    pool_steps: int = 160  # steps on one pool before the next
    lr: float = 5e-4
    lr_final: float = 0.02  # the cosine ends at lr * lr_final
    anneal_minutes: float = 0.0  # the cosine's length in minutes when it is shorter than the steps (0: steps)
    clip_grad: float = 1.0
    arch: str = "nafnet"
    width: int = 32
    depth: int = 3
    blocks: int = 1
    position: bool = True
    surrogate: str = "paper-triplet-e2e"
    lens_mix: tuple = (0.2, 0.3, 0.5)  # perfect, nominal, drawn from the space
    low_light: float = 0.3  # fraction of samples at low light
    level_min: float = 0.35
    level_max: float = 1.0
    val_size: int = 48
    photos: tuple = ()  # prepared photo corpus folders (scenes/corpus.py); () = the natural mix alone
    lpips_weight: float = 0.0  # loss = L1 + lpips_weight * LPIPS (the design runs fine-tune at 1)
    val_every: int = 500
    checkpoint_every: int = 100
    seed: int = 0
    threads: int = 0
    device: str = "auto"  # where the network trains (optix_e2e.device); the pools are made on the CPU
    # fp32, or bf16 / fp16 autocast for the network's learned body (optix_e2e.precision); a run
    # resumes only in the precision it was started in (fp32: as before the setting existed)
    precision: str = "fp32"


def _lens_psfs(sur, kind: str, rng, nominal) -> tuple[torch.Tensor, torch.Tensor] | None:
    if kind == "perfect":
        return None
    if kind == "nominal":
        v = nominal
    else:
        u = torch.as_tensor(rng.random(sur.cfg.n_params), dtype=torch.float64)
        v = (sur.param_min + (sur.param_max - sur.param_min) * (0.02 + 0.96 * u)).float()
    with torch.no_grad():
        return sur.psfs(v, check=False)


@dataclass
class Pool:
    raw: torch.Tensor  # [N, 1, S, S] DN
    ideal: torch.Tensor  # [N, 3, S, S] uint8
    offset: torch.Tensor  # [N, 2] crop centre from the axis, px
    lens: list  # [N] lens kind
    low: torch.Tensor  # [N] bool: low light


def make_pool(
    cfg: PretrainConfig,
    n: int,
    seed,
    sur,
    heights,
    nominal,
    f_number: float,
    *,
    corpus=None,
    mix: dict | None = None,
    progress: bool = False,
) -> Pool:
    """``n`` samples (module doc); deterministic in ``seed``. The sensor is calibrated for the
    space's nominal ``f_number``, as in the design runs. ``corpus`` and ``mix``: the scenes
    (scenes.natural.natural_scene)."""
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(int(np.random.SeedSequence(seed).generate_state(1)[0]))
    frame = SensorFrame()
    with torch.no_grad():
        s, m = cfg.crop, int(sur.psfs(nominal, check=False)[0].shape[-1]) // 2
    presets = {False: calibrated_preset("imx249", f_number), True: calibrated_preset("imx249", f_number, 0.01, 100.0)}
    p_lens = np.asarray(cfg.lens_mix, float) / sum(cfg.lens_mix)
    raws, ideals, offs, kinds, lows = [], [], [], [], []
    for _ in tqdm(range(n), desc="ISP pre-training pool", unit="img", disable=not progress, leave=False):
        kind = LENS_KINDS[rng.choice(3, p=p_lens)]
        scene = natural_scene(s + 2 * m, rng, mix, corpus)
        level = float(np.exp(rng.uniform(math.log(cfg.level_min), math.log(cfg.level_max))))
        lin = color.srgb_to_linear(scene)[None] * level
        y0 = 2 * int(rng.integers(0, (frame.height - s) // 2 + 1))
        x0 = 2 * int(rng.integers(0, (frame.width - s) // 2 + 1))
        off = frame.offset(y0, x0, s)
        psfs = _lens_psfs(sur, kind, rng, nominal)
        with torch.no_grad():
            if psfs is None:
                img = lin
            else:
                img = render(lin, psfs[0], heights, psfs[1], patch=64, full_field_px=frame.full_field_px, offset_px=off)
            img = img[..., m : m + s, m : m + s]
            low = bool(rng.random() < cfg.low_light)
            raw = simulate_raw(img.clamp(min=0), presets[low], quantize="uniform", generator=gen)
        ideal = color.linear_to_srgb(lin[..., m : m + s, m : m + s].clamp(0, 1))
        raws.append(raw)
        ideals.append((ideal * 255).round().to(torch.uint8))
        offs.append(off)
        kinds.append(kind)
        lows.append(low)
    return Pool(torch.cat(raws), torch.cat(ideals), torch.tensor(offs, dtype=torch.float32), kinds, torch.tensor(lows))


def _psnr(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    # metrics.image.psnr gives inf for identical images; the curve is written to JSON/CSV and
    # must stay finite, so the MSE is floored (100 dB)
    mse = ((x - y) ** 2).flatten(1).mean(1).clamp(min=1e-10)
    return -10 * torch.log10(mse)


@torch.no_grad()
def validate(model: SoftwareISP, pool: Pool, batch: int = 8) -> dict:
    """Mean PSNR (8-bit output, as a file holds it) per lens kind and light, and overall."""
    model.eval()
    ps = []
    full = SensorFrame().full_field_px
    dev = next(model.parameters()).device
    for i in range(0, pool.raw.shape[0], batch):
        sl = slice(i, i + batch)
        out = model(pool.raw[sl].to(dev), pool.offset[sl], full).clamp(0, 1)
        ps.append(_psnr((out * 255).round() / 255, pool.ideal[sl].to(dev).float() / 255).cpu())
    model.train()
    ps = torch.cat(ps)
    res = {"psnr_db": float(ps.mean())}
    for kind in LENS_KINDS:
        for low in (False, True):
            sel = torch.tensor([k == kind for k in pool.lens]) & (pool.low == low)
            if sel.any():
                res[f"psnr_db_{kind}_{'low' if low else 'normal'}"] = float(ps[sel].mean())
    return res


def _resumable(cfg: PretrainConfig, photos_digest: str | None = None) -> dict:
    """The settings a resumed run must share with the run it continues (JSON-like): the
    photographs by their corpora's digest, not their folders' paths."""
    out = {
        k: list(v) if isinstance(v, tuple) else v
        for k, v in asdict(cfg).items()
        if k not in ("steps", "minutes", "threads", "anneal_minutes", "device", "photos")
        and (k, v) not in (("precision", "fp32"), ("lpips_weight", 0.0))
    }
    if photos_digest:
        out["photos_digest"] = photos_digest
    return out


def export(model: SoftwareISP, path: Path, meta: dict) -> None:
    """The weights in float16 with their manifest (``meta``): the shipped form."""
    sd = {
        k: (v.half() if v.is_floating_point() and not k.startswith("classical.") else v).cpu()
        for k, v in model.state_dict().items()
    }
    save_atomic({"format": "optix-software-isp/2", "config": model.config(), "state_dict": sd, "meta": meta}, path)


def pretrain(
    cfg: PretrainConfig, out: "str | Path", *, init: "str | Path | None" = None, progress: bool = True, log=print
) -> dict:
    """Train (or continue from out/state.pt) and write state.pt, software_isp.pt (float16),
    curve.csv, train.json and tb/ into ``out``. ``init``: a software ISP checkpoint whose
    weights a new run starts from (its architecture must be the config's; the optimizer
    starts afresh); its training record is kept in the new one's manifest."""

    from ..io import claim_out_dir

    out = Path(out)
    dev = resolve_device(cfg.device)  # a GPU that is not there is refused before the folder is claimed
    amp = resolve_precision(cfg.precision, dev)
    claim_out_dir(out, "ISP pre-training", {"tb"}, marker="state.pt")  # tb/: a start that stopped early
    out.mkdir(parents=True, exist_ok=True)
    set_threads(cfg.threads)
    from ..scenes.corpus import PhotoCorpus

    corpus = PhotoCorpus(cfg.photos, "train") if cfg.photos else None
    val_corpus = PhotoCorpus(cfg.photos, "val") if cfg.photos else None
    digest = corpus.digest if corpus is not None else None
    lpips = None
    if cfg.lpips_weight:
        from ..metrics.lpips import LPIPS

        lpips = LPIPS().to(dev)
    sur = load_surrogate(cfg.surrogate, calibrated_preset("imx249").pixel_um)
    heights = nominal_field_heights(sur)
    space, base = space_and_base(sur.manifest)
    nominal = torch.as_tensor(space.values(base.data), dtype=torch.float32)
    f_number = base_lens_f_number(sur)
    torch.manual_seed(cfg.seed)
    model = SoftwareISP(arch=cfg.arch, base=cfg.width, depth=cfg.depth, blocks=cfg.blocks, position=cfg.position)
    model.calibrate(calibrated_preset("imx249", f_number))
    model.to(dev)  # the pools stay on the CPU (seeded data); each batch goes to the device once
    apply_precision(model, amp)
    scaler = grad_scaler(dev, amp)  # fp16 only (started afresh on a resume)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    state_path = out / "state.pt"
    step, seconds, curve, earlier = 0, 0.0, [], []
    if init is not None and not state_path.is_file():
        start = SoftwareISP.load(init)
        if start.config() != model.config():
            raise InputError(f"{init}: a {start.config()} network, not the {model.config()} this run trains")
        model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in start.state_dict().items()})
        model.calibrate(calibrated_preset("imx249", f_number))
        meta0 = start.meta
        earlier = list(meta0.get("earlier_training", [])) + [{k: meta0.get(k) for k in ("command", "steps", "minutes")}]
        log(f"starting from the weights of {init} ({meta0.get('steps')} steps)")
    if state_path.is_file():
        st = load_plain(state_path, "ISP pre-training state")
        if not isinstance(st, dict) or st.get("format") != FORMAT:
            raise InputError(f"{state_path}: not an ISP pre-training state ({FORMAT})")
        if st.get("config") != _resumable(cfg, digest):
            raise InputError(f"{state_path}: made with other settings; use another --out or the same settings")
        try:  # a damaged state (other weight keys or shapes, a missing entry): one line, not a traceback
            model.load_state_dict(st["model"])
            opt.load_state_dict(st["optimizer"])
            step, seconds, curve = int(st["step"]), float(st["seconds"]), list(st["curve"])
            earlier = list(st.get("earlier_training", []))
        except (KeyError, RuntimeError, TypeError, ValueError) as err:
            what = f"no {err}" if isinstance(err, KeyError) else " ".join(str(err).split())[:300]
            raise InputError(f"{state_path}: damaged ISP pre-training state ({what}); use another --out") from None
        model.calibrate(calibrated_preset("imx249", f_number))  # the classical path: today's calibration
        log(f"resuming ISP pre-training at step {step} ({seconds / 60:.1f} min done)")
    n_params = sum(p.numel() for p in model.parameters())
    val = make_pool(
        cfg,
        cfg.val_size,
        [7, cfg.seed, 0],
        sur,
        heights,
        nominal,
        f_number,
        corpus=val_corpus,
        mix={"corpus_photo": 1.0} if val_corpus is not None else None,
    )
    writer = tensorboard_writer(out / "tb")
    model.train()
    t0, pool, pool_id = time.time() - seconds, None, None
    t_call, start_step = time.time(), step
    bar = tqdm(total=cfg.steps, initial=step, desc="pre-train software ISP", unit="step", disable=not progress)

    def save():
        stop_if_diverged(step, state_path, "lower --lr", software_isp=model)  # never a NaN state over a good one
        save_atomic(
            {
                "format": FORMAT,
                "config": _resumable(cfg, digest),
                "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "step": step,
                "seconds": time.time() - t0,
                "curve": curve,
                "earlier_training": earlier,
            },
            state_path,
        )

    def record() -> dict:
        """Validate and add a point to the curve."""
        v = validate(model, val)
        curve.append(
            {
                "step": step,
                "minutes": round((time.time() - t0) / 60, 2),
                "lr": lr,
                "loss": round(loss.item(), 5),
                **{k: round(x, 3) for k, x in v.items()},
            }
        )
        return v

    while step < cfg.steps:
        if cfg.minutes and time.time() - t_call > 60 * cfg.minutes:
            if step > start_step and (not curve or curve[-1]["step"] != step):  # the curve ends at the stop
                record()
            break
        if pool_id != step // cfg.pool_steps:
            pool_id = step // cfg.pool_steps
            pool = make_pool(cfg, cfg.pool, [6, cfg.seed, pool_id], sur, heights, nominal, f_number, corpus=corpus)
        rng = np.random.default_rng([8, cfg.seed, step])
        idx = torch.as_tensor(rng.integers(pool.raw.shape[0], size=cfg.batch))
        pred = model(pool.raw[idx].to(dev), pool.offset[idx], SensorFrame().full_field_px)
        target = pool.ideal[idx].to(dev).float() / 255
        loss = (pred - target).abs().mean()
        if lpips is not None:
            loss = loss + cfg.lpips_weight * lpips(pred, target).mean()
        stop_if_diverged(step + 1, state_path, "lower --lr", loss=loss.detach())
        opt.zero_grad(set_to_none=True)
        scaled_backward(loss, opt, scaler)
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.clip_grad)
        lr = cosine_lr(cfg.lr, step, cfg.steps, (time.time() - t0) / 60, cfg.anneal_minutes, cfg.lr_final)
        for g in opt.param_groups:
            g["lr"] = lr
        scaled_step(opt, scaler)
        step += 1
        writer.add_scalar("train/loss", loss.item(), step)
        bar.update(1)
        bar.set_postfix(loss=f"{loss.item():.4f}")
        if step % cfg.val_every == 0 or step == cfg.steps:
            v = record()
            for k, x in v.items():
                writer.add_scalar(f"val/{k}", x, step)
            bar.write(
                f"step {step}: val PSNR {v['psnr_db']:.2f} dB "
                f"(perfect lens {v.get('psnr_db_perfect_normal', float('nan')):.2f}, "
                f"nominal {v.get('psnr_db_nominal_normal', float('nan')):.2f}, "
                f"low light nominal {v.get('psnr_db_nominal_low', float('nan')):.2f})"
            )
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            save()
    save()
    bar.close()
    writer.close()
    meta = {
        # `optix ...` or `python -m optix_e2e ...` (argv[0] is then the package's __main__.py)
        "command": "optix " + " ".join(sys.argv[1:])
        if Path(sys.argv[0]).name == "optix" or Path(sys.argv[0]).parent.name == "optix_e2e"
        else "pretrain()",
        "config": asdict(cfg),
        "steps": step,
        "device": str(dev),  # where this call trained
        "precision": cfg.precision,
        "minutes": round((time.time() - t0) / 60, 1),
        "parameters": n_params,
        "curve": curve,
        "earlier_training": earlier,
        "data": (
            "photographs of the corpora below and a minority of procedural scenes"
            if corpus
            else "natural training scenes"
        )
        + f" through the perfect lens, the nominal and lenses drawn from {cfg.surrogate} (its surrogate's PSFs), "
        "normal and low light, crops all over the frame",
        "photos": corpus.record() if corpus is not None else None,
        "validation": val_corpus.record() if val_corpus is not None else "the natural mix, its own seed",
    }
    export(model, out / "software_isp.pt", meta)
    keys = sorted({k for c in curve for k in c}, key=lambda k: (k != "step", k))
    lines = [",".join(keys)] + [",".join(str(c.get(k, "")) for k in keys) for c in curve]
    write_text_atomic(out / "curve.csv", "".join(line + "\n" for line in lines))
    write_record_atomic(out / "train.json", meta)
    return meta
