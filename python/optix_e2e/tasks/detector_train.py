"""Training and evaluating the detector on a COCO set (``optix detect train|eval``).

Training reads the whole set into memory as 8-bit images, draws each batch from (seed,
step) alone (so a resumed run sees the batches it would have seen), flips half the images
left-right, and runs AdamW with a linear warm-up and a cosine decay over ``steps`` or over
``minutes`` when that budget ends first. The run directory holds ``detector.pt`` (weights,
config, step, optimizer; written atomically every ``checkpoint_every`` steps: the same
command continues a killed run), ``history.csv`` and ``tb/`` (TensorBoard).
"""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path

import numpy as np
import torch

from .. import color
from ..device import resolve_device
from ..errors import InputError
from ..io import claim_out_dir, open_log, require_regular_file, tensorboard_writer, write_text_atomic
from ..parallel import check_finite_weights, stop_if_diverged
from ..precision import apply_precision, grad_scaler, resolve_precision
from ..scenes.coco import CocoDetection
from ..scenes.street import CATEGORIES
from ..torchfile import DAMAGED_STATE_ERRORS
from .detector import detect, in_the_dark, make_detector, mean_average_precision

FORMAT = "optix-detector/1"


def load_coco_folder(folder: "str | Path") -> tuple[torch.Tensor, list[dict], CocoDetection]:
    """A COCO folder (images/ + annotations.json, as ``optix scenes street`` writes) as uint8
    images [N, 3, H, W] and targets; every image must have the same size."""
    folder = Path(folder)
    if (folder / "annotations.json").exists():  # a missing one: CocoDetection's own error below
        require_regular_file(folder / "annotations.json", "COCO annotation file")  # a FIFO would block
    ds = CocoDetection(folder / "images", folder / "annotations.json")
    if len(ds) == 0:
        raise InputError(f"{folder}: the annotation file lists no images")
    ours = {c["id"]: c["name"] for c in CATEGORIES}
    for cid, name in sorted(ds.categories.items()):  # the detector's classes are the street set's
        if ours.get(cid) != name:
            raise InputError(
                f"{folder / 'annotations.json'}: category {cid} {name!r} is not one the detector "
                f"knows ({', '.join(f'{k} {v!r}' for k, v in ours.items())})"
            )
    sizes = {(im["height"], im["width"]) for im in ds.images}
    if len(sizes) != 1:
        raise InputError(
            f"{folder}: images of several sizes ({', '.join(f'{h}x{w}' for h, w in sorted(sizes))}); "
            f"the detector trains on one size"
        )
    imgs, targets = [], []
    for i in range(len(ds)):
        img, t = ds[i]
        imgs.append((img * 255 + 0.5).to(torch.uint8))
        targets.append(t)
    return torch.stack(imgs), targets, ds


MAX_STEPS = 10_000_000  # the command line's maximum of --steps


def save_detector(path: Path, model, config: dict, **extra) -> None:
    from ..io import save_atomic

    save_atomic({"format": FORMAT, "config": config, "state_dict": model.state_dict(), **extra}, path)


def load_detector(path: "str | Path"):
    """(model, checkpoint dict) from a detector.pt or its run directory; plain data only."""
    from ..torchfile import build_module, load_plain

    path = Path(path)
    if path.is_dir():
        path = path / "detector.pt"
    ck = load_plain(path, "detector checkpoint")
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        raise InputError(f"{path}: not a detector checkpoint ({FORMAT})")
    _check_record(ck, path)
    cfg = ck.get("config")
    model = build_module(
        lambda **c: make_detector(**{**c, "image_size": tuple(c["image_size"])}),
        cfg,
        ck.get("state_dict"),
        path,
        "detector checkpoint",
    )
    return model, ck


def _check_record(ck: dict, path: Path) -> None:
    """The training record every detector checkpoint carries: its step and wall time."""
    checks = {
        "step": lambda v: isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_STEPS,
        "wall_s": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0,
    }
    for key, ok in checks.items():
        if key not in ck or not ok(ck[key]):
            what = "missing" if key not in ck else f"{ck[key]}"[:40]
            raise InputError(f"{path}: damaged detector checkpoint ({key} {what}); remove it to train from the start")


HISTORY_HEADER = ["step", "loss", "classification", "bbox_regression", "bbox_ctrness", "lr", "seconds"]


def _history_is_ours(out: Path) -> bool:
    """Whether a history.csv in ``out`` is a detector run's (what a run stopped before its
    first checkpoint leaves, by divergence say: that run starts again there)."""
    if not (out / "history.csv").exists():
        return True
    try:
        first = (out / "history.csv").read_text(encoding="utf-8").splitlines()[:1]
    except (OSError, UnicodeDecodeError):
        return False
    return first in ([], [",".join(HISTORY_HEADER)])


# The noisy images (``noise``): the design run's sensor at dusk (tasks/detection.py): the IMX249's
# full well and read noise, the stored image's white (the scene's sunlit white) at a log-uniform
# 0.1-0.4 of the calibrated 85 % of the full well, through f/4.4 .. f/3.2 (1 .. 1.89 x the photons)
NOISE_FULL_WELL_E, NOISE_READ_E, NOISE_WHITE = 32513.0, 7.0, 0.85
NOISE_LEVELS, NOISE_APERTURE_GAIN = (0.1, 0.4), (1.0, (4.4 / 3.2) ** 2)


def sensor_noise(x_lin: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """Photon (Poisson) and read (Gaussian) noise on a linear image whose 1.0 is the scene's
    sunlit white, at a random dusk exposure (the constants above); linear, clipped to [0, 1]."""
    level = float(np.exp(rng.uniform(*np.log(NOISE_LEVELS)))) * float(rng.uniform(*NOISE_APERTURE_GAIN))
    per_unit = NOISE_FULL_WELL_E * NOISE_WHITE * level  # electrons for linear 1.0
    gen = torch.Generator().manual_seed(int(rng.integers(2**62)))
    e = torch.poisson(x_lin.clamp_min(0.0) * per_unit, generator=gen)
    e = e + NOISE_READ_E * torch.randn(x_lin.shape, generator=gen)
    return (e / per_unit).clamp(0.0, 1.0)


def _batch(
    images: torch.Tensor, targets: list[dict], seed: int, step: int, batch: int, dim: float = 1.0, noise: float = 0.0
):
    """A training batch drawn from (seed, step): ``dim``: each image darkened by a log-uniform
    factor in [dim, 1] in linear light; ``noise``: the fraction of images given sensor_noise."""
    rng = np.random.default_rng([5, int(seed), int(step)])  # stream tag 5: detector batches
    idx = rng.choice(len(images), size=min(batch, len(images)), replace=False)
    flip = rng.random(len(idx)) < 0.5
    xs, ts = [], []
    w = images.shape[-1]
    for i, f in zip(idx.tolist(), flip.tolist()):
        x, b = images[i].float() / 255, targets[i]["boxes"].clone()
        noisy = noise > 0.0 and rng.random() < noise
        if dim < 1.0 or noisy:  # a dimmer exposure of the same scene: scaled in linear light
            lin = color.srgb_to_linear(x)
            if dim < 1.0:
                lin = lin * float(np.exp(rng.uniform(np.log(dim), 0.0)))
            if noisy:
                lin = sensor_noise(lin, rng)
            x = color.linear_to_srgb(lin)
        if f:
            x = x.flip(-1)
            b[:, [0, 2]] = w - b[:, [2, 0]]
        xs.append(x)
        ts.append({"boxes": b, "labels": targets[i]["labels"]})
    return xs, ts


def train_detector(
    data: "str | Path",
    out: "str | Path",
    *,
    steps: int = 4000,
    minutes: float | None = None,
    batch: int = 8,
    lr: float = 2e-3,
    seed: int = 0,
    width: int = 32,
    fpn: int = 64,
    dim: float = 1.0,
    noise: float = 0.0,
    checkpoint_every: int = 100,
    device: str = "auto",
    precision: str = "fp32",
    progress: bool = True,
    log=print,
) -> dict:
    """Train (or continue) a detector on the COCO folder ``data``; returns the run's summary.
    ``device``: where the detector trains (optix_e2e.device; a run may resume on another);
    the batches are drawn on the CPU from (seed, step) and go there once per step.
    ``precision``: fp32, or bf16 / fp16 autocast for the backbone and head (optix_e2e.precision;
    the losses in float32; fp16 with a gradient scaler, started afresh on a resume)."""
    from tqdm import tqdm

    dev = resolve_device(device)
    amp = resolve_precision(precision, dev)
    out = Path(out)
    images, targets, _ = load_coco_folder(data)
    size = tuple(images.shape[-2:])
    config = {"width": width, "fpn": fpn, "image_size": list(size)}
    ck_path = out / "detector.pt"
    torch.manual_seed(seed)
    if ck_path.is_file():
        model, ck = load_detector(ck_path)
        check_finite_weights(model.state_dict(), ck_path)
        if (
            ck["config"] != config
            or ck.get("data") != str(Path(data).resolve())
            or ck.get("seed") != seed
            or ck.get("dim", 1.0) != dim
            or ck.get("noise", 0.0) != noise
        ):
            raise InputError(
                f"{out} holds a detector trained with other settings (config {ck['config']}, data "
                f"{ck.get('data')}, seed {ck.get('seed')}, dim {ck.get('dim', 1.0)}, noise {ck.get('noise', 0.0)}); "
                f"use another --out"
            )
        step, wall = ck["step"], float(ck["wall_s"])  # checked by load_detector; a larger --steps continues
        log(f"resuming at step {step} of {steps}")
    else:
        claim_out_dir(out, "detector run", {"history.csv", "tb"}, marker="detector.pt", own=_history_is_ours)
        out.mkdir(parents=True, exist_ok=True)
        model, ck, step, wall = make_detector(width, fpn, size), None, 0, 0.0
    model.to(dev)
    apply_precision(model, amp)
    scaler = grad_scaler(dev, amp)
    opt = torch.optim.AdamW(model.parameters(), lr, weight_decay=1e-4)
    if ck is not None:
        try:
            opt.load_state_dict(ck["optimizer"])
        except DAMAGED_STATE_ERRORS as err:
            raise InputError(
                f"{ck_path}: damaged detector checkpoint (optimizer: {type(err).__name__}: {err}); "
                f"remove it to train from the start"
            ) from None
    budget_s = None if minutes is None else 60.0 * minutes

    def lr_at(s: int, frac: float) -> float:  # warm-up, then cosine to 1 % by the budget's end
        warm = min(1.0, (s + 1) / 100)
        return lr * warm * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0))))

    writer = tensorboard_writer(out / "tb")
    hist_path = out / "history.csv"
    if hist_path.is_file():  # rows written after the checkpoint we resume from are run again: drop them
        lines = hist_path.read_text().splitlines(keepends=True)
        keep = lines[:1] + [ln for ln in lines[1:] if ln.split(",")[0].isdigit() and int(ln.split(",")[0]) <= step]
        write_text_atomic(hist_path, "".join(keep))
    new_hist = not hist_path.is_file()
    hist = open_log(hist_path)
    hw = csv.writer(hist)
    if new_hist:
        hw.writerow(HISTORY_HEADER)
    model.train()
    t0 = time.perf_counter()

    def checkpoint() -> None:
        save_detector(
            ck_path,
            model,
            config,
            optimizer=opt.state_dict(),
            step=step,
            steps=steps,
            seed=seed,
            dim=dim,
            noise=noise,
            wall_s=wall + time.perf_counter() - t0,
            data=str(Path(data).resolve()),
            device=str(dev),  # where the last call trained
            precision=precision,  # and in what arithmetic
        )

    bar = tqdm(total=steps, initial=step, desc="detector", unit="step", disable=not progress)
    try:
        while step < steps:
            elapsed = wall + time.perf_counter() - t0
            if budget_s is not None and elapsed >= budget_s:
                log(f"time budget reached at step {step}")
                break
            frac = step / steps if budget_s is None else max(step / steps, elapsed / budget_s)
            for g in opt.param_groups:
                g["lr"] = lr_at(step, frac)
            ts = time.perf_counter()
            xs, tg = _batch(images, targets, seed, step, batch, dim, noise)
            xs, tg = [x.to(dev) for x in xs], [{k: v.to(dev) for k, v in t.items()} for t in tg]
            losses = model(xs, tg)
            loss = sum(losses.values())
            stop_if_diverged(step + 1, ck_path, "lower --lr", loss=loss.detach())
            opt.zero_grad()
            if scaler is None:
                loss.backward()
                opt.step()
            else:
                scaler.scale(loss).backward()
                scaler.step(opt)  # skipped where the gradients overflowed
                scaler.update()
            step += 1
            hw.writerow(
                [
                    step,
                    f"{loss.item():.6g}",
                    *(f"{losses[k].item():.6g}" for k in ("classification", "bbox_regression", "bbox_ctrness")),
                    f"{opt.param_groups[0]['lr']:.3g}",
                    f"{time.perf_counter() - ts:.4f}",
                ]
            )
            writer.add_scalar("detector/loss", loss.item(), step)
            bar.update(1)
            bar.set_postfix(loss=f"{loss.item():.3f}")
            if step % checkpoint_every == 0 or step == steps:
                hist.flush()
                stop_if_diverged(step, ck_path, "lower --lr", detector=model)
                checkpoint()
    finally:
        bar.close()
        hist.close()
        writer.close()
    stop_if_diverged(step, ck_path, "lower --lr", detector=model)
    checkpoint()
    wall += time.perf_counter() - t0
    return {
        "run": str(out),
        "steps": step,
        "wall_s": wall,
        "n_images": len(images),
        "n_objects": int(sum(len(t["labels"]) for t in targets)),
        "image_size": list(size),
        "device": str(dev),
        "precision": precision,
    }


def evaluate_detector(model, data: "str | Path", batch: int = 8, dark: float = 0.1) -> dict:
    """mAP of ``model`` on the COCO folder ``data``, and mAP@0.5 over the objects in the dark
    (mean illumination < ``dark`` of the sunlight, where the file says so) with the other
    objects' boxes removed from both sides."""
    images, targets, ds = load_coco_folder(data)
    if not any(len(t["labels"]) for t in targets):
        raise InputError(f"{data}: no objects to score (the annotation file lists none that is not a crowd)")
    preds = detect(model, images.float() / 255, batch)
    res = mean_average_precision(preds, targets)
    if any(im["illumination"] for im in ds.images) and all(
        x is not None for im in ds.images for x in im["illumination"]
    ):
        lights = [torch.tensor(im["illumination"], dtype=torch.float32).reshape(-1) for im in ds.images]
        r = mean_average_precision(*in_the_dark(preds, targets, lights, dark))
        none = r["n_objects"] == 0  # no object in the dark: nothing to score (torchmetrics says -1)
        res["dark"] = {
            "threshold": dark,
            "map_50": None if none else r["map_50"],
            "map": None if none else r["map"],
            "n_objects": r["n_objects"],
        }
    return res
