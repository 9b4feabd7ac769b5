"""Held-out evaluation of trained cameras, and the paired comparison of two of them.

Every figure is measured on the fixed held-out set (tasks/samples.py) with the camera's final
processing (the reference ISP for a hardware ISP), sensor noise on with a fixed seed per
sample (the same for every camera: paired), and the optics given: the exact engine's PSFs of
the lens for the figures we report, the surrogate's for comparison.

The paired comparison averages each image's metric over its positions, takes the differences
(end-to-end minus nominal) per image, and gives their mean with a 95 % percentile bootstrap
interval over images (resampled with a fixed seed). ``paired_by_zone`` does the same with
only the samples whose crop centre lies in the inner or the outer half of the field.
"""

from __future__ import annotations

import numpy as np
import torch

from ..metrics.image import haarpsi, psnr, ssim
from ..metrics.lpips import lpips
from ..errors import InputError

METRICS = ("psnr_db", "ssim", "lpips", "haarpsi")


@torch.no_grad()
def evaluate(camera, samples) -> list[dict]:
    """Per-sample metrics of ``camera`` (a Camera) on held-out ``samples``; the camera's
    final output as an 8-bit image file would hold it (clamped to [0, 1], rounded to 1/255)."""
    camera.eval()
    rows = []
    for s in samples:
        gen = torch.Generator().manual_seed(int(s.noise_seed))
        out, _ = camera(s.scene[None], s.offset_px, gen, final=True)
        x, y = (out.clamp(0, 1) * 255).round() / 255, s.target[None]
        radius = float(np.hypot(*s.offset_px)) / camera.optics.full_field_px if camera.optics.full_field_px else 0.0
        rows.append(
            {
                "image": s.name,
                "position": s.position,
                "radius": radius,
                "psnr_db": float(psnr(x, y)[0]),
                "ssim": float(ssim(x, y)[0]),
                "lpips": float(lpips(x, y)[0]),
                "haarpsi": float(haarpsi(x, y)[0]),
            }
        )
    return rows


ZONES = {"inner": (0.0, 0.5), "outer": (0.5, 2.0)}  # the crop centre's radius, a fraction of the full field


def in_zone(rows: list[dict], zone: str) -> list[dict]:
    lo, hi = ZONES[zone]
    return [r for r in rows if lo <= r.get("radius", 0.0) < hi]


def summarize(rows: list[dict]) -> dict:
    """Means over samples, 1 - LPIPS (the paper's perceptual score), per-position and
    per-zone (inner / outer half of the field) means."""
    out = {m: float(np.mean([r[m] for r in rows])) for m in METRICS}
    out["one_minus_lpips"] = 1.0 - out["lpips"]
    out["n_samples"] = len(rows)
    out["by_position"] = {
        p: {m: float(np.mean([r[m] for r in rows if r["position"] == p])) for m in METRICS}
        for p in sorted({r["position"] for r in rows})
    }
    out["by_zone"] = {
        z: {"n_samples": len(zr), **{m: float(np.mean([r[m] for r in zr])) for m in METRICS}}
        for z in ZONES
        if (zr := in_zone(rows, z))
    }
    return out


def per_image(rows: list[dict], metric: str) -> dict[str, float]:
    vals: dict[str, list[float]] = {}
    for r in rows:
        vals.setdefault(r["image"], []).append(r[metric])
    return {k: float(np.mean(v)) for k, v in vals.items()}


def paired(a_rows: list[dict], b_rows: list[dict], n_boot: int = 2000, seed: int = 0) -> dict:
    """Mean of b - a per image and its 95 % bootstrap interval, for every metric."""
    out = {}
    rng = np.random.default_rng(seed)
    images = sorted(per_image(a_rows, METRICS[0]))
    idx = rng.integers(0, len(images), size=(n_boot, len(images)))
    for m in METRICS:
        a, b = per_image(a_rows, m), per_image(b_rows, m)
        if sorted(b) != images:
            raise InputError("paired comparison needs the same held-out images on both sides")
        d = np.array([b[k] - a[k] for k in images])
        boots = d[idx].mean(1)
        lo, hi = np.percentile(boots, [2.5, 97.5])
        out[m] = {
            "mean": float(d.mean()),
            "ci95": [float(lo), float(hi)],
            "n_images": len(images),
            "better": "higher" if m != "lpips" else "lower",
        }
    return out


def paired_by_zone(a_rows: list[dict], b_rows: list[dict], n_boot: int = 2000, seed: int = 0) -> dict:
    """``paired`` restricted to each zone's samples (the same samples on both sides)."""
    return {z: paired(in_zone(a_rows, z), in_zone(b_rows, z), n_boot, seed) for z in ZONES if in_zone(a_rows, z)}
