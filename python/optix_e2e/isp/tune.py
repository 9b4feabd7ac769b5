"""Tuning the hardware ISP's hyperparameters through its differentiable proxy.

Adam on the range-normalized hyperparameters (a sigmoid keeps them inside their ranges; the
categorical demosaick choice is relaxed to [0, 1] and rounded at the end) minimizes an
image-quality loss, L1 + w * (1 - HaarPSI), between the proxy's output and the ideal
rendering of procedural training scenes. The result is then checked with the *true*
reference ISP on held-out photos, default settings against tuned settings.
"""

from __future__ import annotations

import numpy as np
import torch
from tqdm import tqdm

from ..metrics import image as metrics
from . import data, evaluate
from . import params as hp
from .proxy import ISPProxy


def _logit(u: np.ndarray) -> torch.Tensor:
    u = np.clip(u, 0.02, 0.98)
    return torch.tensor(np.log(u / (1 - u)), dtype=torch.float32)


def tune_params(
    proxy: ISPProxy,
    *,
    steps: int = 200,
    n_scenes: int = 48,
    size: int = 128,
    lr: float = 0.05,
    perceptual_weight: float = 1.0,
    seed: int = 0,
    start: dict | None = None,
    progress: bool = True,
) -> tuple[dict, list[float]]:
    """Returns (tuned hyperparameters, loss history)."""
    proxy.eval()
    for p in proxy.parameters():
        p.requires_grad_(False)
    rng = np.random.default_rng(seed)
    scene = torch.stack([data.training_scene(size, rng) for _ in range(n_scenes)])
    raw, ideal = data.capture_raw(scene, rng, data.Capture(), torch.Generator().manual_seed(seed))
    dev = next(proxy.parameters()).device  # drawn on the CPU (seeded), moved once
    raw, ideal = raw.to(dev), ideal.to(dev)
    z = _logit(hp.to_unit(start or hp.defaults())).to(dev).requires_grad_(True)
    opt = torch.optim.Adam([z], lr=lr)
    history = []
    for _ in tqdm(range(steps), desc="tune ISP", unit="step", disable=not progress):
        idx = torch.as_tensor(rng.integers(n_scenes, size=8), device=dev)
        out = proxy(raw[idx], torch.sigmoid(z))
        loss = (out - ideal[idx]).abs().mean() + perceptual_weight * metrics.perceptual_distance(
            out.clamp(0, 1), ideal[idx]
        ).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        history.append(loss.item())
    return hp.from_unit(torch.sigmoid(z).detach().cpu().numpy()), history


def true_isp_quality(params: dict, *, size: int = 256, photos=None, seed: int = evaluate.HELD_OUT_SEED) -> dict:
    """The reference ISP's output on held-out photos against their ideal renderings."""
    names, raw, ideal = evaluate.held_out_captures(size, photos, seed)
    out = data.reference_isp()(raw, [params] * len(names))
    per = [metrics.summarize(out[i : i + 1], ideal[i : i + 1]) for i in range(len(names))]
    return {
        "psnr_db": float(np.mean([r["psnr_db"] for r in per])),
        "ssim": float(np.mean([r["ssim"] for r in per])),
        "haarpsi": float(np.mean([r["haarpsi"] for r in per])),
        "per_photo": dict(zip(names, per)),
    }
