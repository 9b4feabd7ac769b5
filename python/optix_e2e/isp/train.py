"""Training of the hardware ISP's proxy (Eq. 9) with TensorBoard logs and a tqdm progress
bar: L1 + perceptual loss against the reference ISP's output on sensor RAW over random
hyperparameters. (The software ISP is pre-trained through lenses of the design space:
camera_design/isp_pretraining.py.)

Data stream: pools of procedural scenes captured by the simulated sensor and rendered by the
reference ISP under random hyperparameters (``data.make_pool``); a fresh pool replaces the
old one every ``refresh_every`` steps, so the network rarely sees a pair twice.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ..device import resolve_device
from ..io import tensorboard_writer, write_record_atomic
from ..metrics import image as metrics
from ..parallel import set_threads, stop_if_diverged
from ..precision import apply_precision, grad_scaler, resolve_precision, scaled_backward, scaled_step
from . import data
from .proxy import ISPProxy


@dataclass
class TrainConfig:
    steps: int = 8000
    batch: int = 16
    patch: int = 64
    pool: int = 3072
    refresh_every: int = 1500
    lr: float = 1e-3
    clip_grad: float = 0.5  # max gradient norm per step
    perceptual_weight: float = 0.1  # weight of (1 - HaarPSI) next to L1
    crop: int = 4  # border pixels left out of loss and metrics
    base: int = 32
    depth: int = 3
    seed: int = 0
    minutes: float = 0.0  # stop after this wall time (0 = run all steps)
    val_every: int = 250
    val_size: int = 128
    threads: int = 0  # torch threads (0 = torch's default)
    device: str = "auto"  # where the proxy trains (optix_e2e.device); the pools are made on the CPU
    precision: str = "fp32"  # fp32, or bf16 / fp16 autocast for the proxy's UNet (optix_e2e.precision)


def _crop(x: torch.Tensor, c: int) -> torch.Tensor:
    return x[..., c : x.shape[-2] - c, c : x.shape[-1] - c] if c else x


def cosine_lr(
    lr: float, step: int, steps: int, minutes_done: float = 0.0, anneal_minutes: float = 0.0, final: float = 0.02
) -> float:
    """Cosine decay from ``lr`` to ``final`` x ``lr`` over ``steps``, or over ``anneal_minutes``
    of training when those run out first (so a time-boxed CPU run still anneals)."""
    frac = step / max(steps, 1)
    if anneal_minutes:
        frac = max(frac, minutes_done / anneal_minutes)
    return lr * (final + (1 - final) * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0))))


def _predict(model, kind: str, pool: data.Pool, idx) -> tuple[torch.Tensor, torch.Tensor]:
    """(prediction, target) of a batch: the proxy imitates the reference ISP. The pool lives on
    the CPU (the reference ISP made it there); the batch goes to the model's device once."""
    dev = next(model.parameters()).device
    raw, u, target = (t.to(dev) for t in pool.batch(idx))
    return model(raw, u), target


@torch.no_grad()
def validate(model, pool: data.Pool, crop: int, batch: int = 16, kind: str = "proxy") -> dict:
    model.eval()
    ps, ss = [], []
    for i in range(0, pool.raw.shape[0], batch):
        pred, target = _predict(model, kind, pool, slice(i, i + batch))
        pred = pred.clamp(0, 1)
        ps.append(metrics.psnr(pred, target, crop=crop))
        ss.append(metrics.ssim(pred, target, crop=crop))
    model.train()
    return {"psnr_db": float(torch.cat(ps).mean()), "ssim": float(torch.cat(ss).mean())}


def train_proxy(cfg: TrainConfig, out_dir: Path, *, init: Path | None = None, progress: bool = True) -> dict:
    """Train (or continue training ``init``) and write proxy.pt, train.json and tb/ to out_dir."""
    model = ISPProxy.load(init) if init else ISPProxy(base=cfg.base, depth=cfg.depth)
    return _train(model, "proxy", cfg, Path(out_dir), progress)


def _save(model, kind: str, out_dir: Path, **meta) -> None:
    model.save(out_dir / "proxy.pt", **meta)


def _train(model, kind: str, cfg: TrainConfig, out_dir: Path, progress: bool) -> dict:
    from ..io import claim_out_dir

    out_dir = Path(out_dir)
    dev = resolve_device(cfg.device)  # a GPU that is not there is refused before the folder is claimed
    amp = resolve_precision(cfg.precision, dev)
    claim_out_dir(out_dir, "ISP proxy training", {"proxy.pt", "train.json", "tb"})  # its own files: trained again
    out_dir.mkdir(parents=True, exist_ok=True)
    set_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    model.to(dev)
    apply_precision(model, amp)
    scaler = grad_scaler(dev, amp)  # fp16 only
    meta = getattr(model, "meta", {})  # a continued proxy keeps the record of its earlier runs
    earlier = list(meta.get("earlier_training", [])) + ([meta["training"]] if "training" in meta else [])
    model.train()
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    loss_fn = metrics.L1PerceptualLoss(cfg.perceptual_weight).to(dev)
    writer = tensorboard_writer(out_dir / "tb")
    val_pool = data.make_pool(64, cfg.val_size, seed=10_000 + cfg.seed, progress=False)
    rng = np.random.default_rng(cfg.seed)
    history, t0, pool, step = [], time.time(), None, 0
    bar = tqdm(total=cfg.steps, desc=f"train {kind}", unit="step", disable=not progress)
    for step in range(1, cfg.steps + 1):
        if pool is None or (step - 1) % cfg.refresh_every == 0:
            pool = data.make_pool(cfg.pool, cfg.patch, seed=int(rng.integers(2**31)), progress=progress)
        pred, target = _predict(model, kind, pool, torch.as_tensor(rng.integers(pool.raw.shape[0], size=cfg.batch)))
        loss = loss_fn(_crop(pred, cfg.crop), _crop(target, cfg.crop))
        stop_if_diverged(step, out_dir / "proxy.pt", "lower --lr", loss=loss.detach())
        opt.zero_grad(set_to_none=True)
        scaled_backward(loss, opt, scaler)
        # The perceptual term's gradient has rare spikes (HaarPSI divides by local similarity
        # terms); without clipping one of them blew a run up at step ~475.
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.clip_grad)
        scaled_step(opt, scaler)
        lr = cosine_lr(cfg.lr, step, cfg.steps, (time.time() - t0) / 60, cfg.minutes)
        for group in opt.param_groups:
            group["lr"] = lr
        writer.add_scalar("train/loss", loss.item(), step)
        bar.update(1)
        bar.set_postfix(loss=f"{loss.item():.4f}")
        out_of_time = cfg.minutes and (time.time() - t0) > 60 * cfg.minutes
        if step % cfg.val_every == 0 or step == cfg.steps or out_of_time:
            val = validate(model, val_pool, cfg.crop, kind=kind)
            writer.add_scalar("val/psnr_db", val["psnr_db"], step)
            writer.add_scalar("val/ssim", val["ssim"], step)
            writer.add_scalar("train/lr", lr, step)
            history.append({"step": step, "loss": loss.item(), **val, "seconds": time.time() - t0})
            stop_if_diverged(step, out_dir / "proxy.pt", "lower --lr", proxy=model)  # before a NaN proxy.pt
            _save(
                model,
                kind,
                out_dir,
                training={"config": asdict(cfg), "steps_done": step, "val": val},
                earlier_training=earlier,
            )
        if out_of_time:
            break
    bar.close()
    writer.close()
    summary = {
        "steps_done": step,
        "seconds": round(time.time() - t0, 1),
        "config": asdict(cfg),
        "device": str(dev),
        "precision": cfg.precision,
        "final_val": history[-1] if history else None,
        "history": history,
    }
    write_record_atomic(out_dir / "train.json", summary)
    return summary
