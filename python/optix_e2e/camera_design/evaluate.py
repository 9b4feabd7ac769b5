"""Held-out evaluation of trained cameras, and the paired comparison of two of them.

Every figure is measured on the fixed held-out set (tasks/samples.py) with the camera's final
processing (the reference ISP for a hardware ISP), sensor noise on with a fixed seed per
sample (the same for every camera: paired), and the optics given: the exact engine's PSFs of
the lens for the figures we report, the surrogate's for comparison.

The headline (``HEADLINE_POSITION``, fixed 2026-11-27 before the wide-space runs, issue 34) is
the "frame" positions: four stratified uniform positions per image. Where an evaluation holds
frame samples, the means (``summarize``) and the paired comparison (``paired``) are over them
alone; the centre and the corner are reported beside them (``by_position``,
``paired_by_position``); an evaluation without frame samples (eval_positions = centre-corner)
is summarized over all its samples.

The paired comparison averages each image's metric over its (headline) positions, takes the
differences (end-to-end minus nominal) per image, and gives their mean with a 95 % percentile
bootstrap interval over images (resampled with a fixed seed). ``paired_by_position`` does the
same with each position's samples alone, ``paired_by_zone`` with the headline samples whose
crop centre lies in the inner or the outer half of the field.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from ..metrics.image import haarpsi, psnr, ssim
from ..metrics.lpips import lpips

METRICS = ("psnr_db", "ssim", "lpips", "haarpsi")

#: the held-out position whose samples give every headline figure, stated once (results.json
#: records it with the reason)
HEADLINE_POSITION = "frame"
HEADLINE_WHY = (
    "frame: 4 stratified uniform positions per image sample the whole sensor as a photo uses it; "
    "fixed 2026-11-27 before the wide-space runs (issue 34); centre and corner are reported beside it"
)
POSITION_ORDER = ("frame", "centre", "corner")  # how results list the positions


def at_position(rows: list[dict], position: str) -> list[dict]:
    return [r for r in rows if r.get("position") == position]


def headline(rows: list[dict]) -> list[dict]:
    """The samples every headline figure is over: those at ``HEADLINE_POSITION`` where there
    are any, else all (an evaluation without frame positions, or rows already of one position)."""
    return at_position(rows, HEADLINE_POSITION) or rows


def headline_position(rows: list[dict]) -> str:
    """What ``headline(rows)`` keeps: ``HEADLINE_POSITION``, or "all" samples."""
    return HEADLINE_POSITION if at_position(rows, HEADLINE_POSITION) else "all"


#: held-out samples per batch: the ISP and the metrics take a batch at a time (a GPU's work in
#: large kernels; on the 2-core CPU 1.1-1.3x); each sample's optics and noise are its own
EVAL_BATCH = 8


@torch.no_grad()
def evaluate(camera, samples, batch: int = EVAL_BATCH) -> list[dict]:
    """Per-sample metrics of ``camera`` (a Camera) on held-out ``samples`` (an iterable: a
    progress bar advances per sample); the camera's final output as an 8-bit image file would
    hold it (clamped to [0, 1], rounded to 1/255). ``batch`` samples go through the ISP and
    the metrics at a time; the figures are those of one at a time."""
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise InputError(f"batch must be an integer >= 1, got {batch!r}")
    camera.eval()
    dev = camera.device  # the samples go to the camera's device; the metrics run there
    rows: list[dict] = []
    group: list = []

    def flush():
        if not group:
            return
        out = camera.final_batch(
            torch.stack([s.scene for s in group]).to(dev),
            [s.offset_px for s in group],
            [torch.Generator().manual_seed(int(s.noise_seed)) for s in group],
        )
        x = (out.clamp(0, 1) * 255).round() / 255
        y = torch.stack([s.target for s in group]).to(dev)
        scores = {"psnr_db": psnr(x, y), "ssim": ssim(x, y), "lpips": lpips(x, y), "haarpsi": haarpsi(x, y)}
        full = camera.optics.full_field_px
        for i, s in enumerate(group):
            rows.append(
                {
                    "image": s.name,
                    "position": s.position,
                    "radius": float(np.hypot(*s.offset_px)) / full if full else 0.0,
                    **{k: float(v[i]) for k, v in scores.items()},
                }
            )
        group.clear()

    for s in samples:
        if group and tuple(s.scene.shape) != tuple(group[0].scene.shape):
            flush()  # a batch holds crops of one size
        group.append(s)
        if len(group) == batch:
            flush()
    flush()
    return rows


ZONES = {"inner": (0.0, 0.5), "outer": (0.5, 2.0)}  # the crop centre's radius, a fraction of the full field


def in_zone(rows: list[dict], zone: str) -> list[dict]:
    lo, hi = ZONES[zone]
    return [r for r in rows if lo <= r.get("radius", 0.0) < hi]


def summarize(rows: list[dict]) -> dict:
    """Means over the headline samples (``headline``: the frame positions where evaluated),
    1 - LPIPS (the paper's perceptual score), their per-zone (inner / outer half of the field)
    means, and the means at every position evaluated (``by_position``: all the samples)."""
    head = headline(rows)
    out = {m: float(np.mean([r[m] for r in head])) for m in METRICS}
    out["one_minus_lpips"] = 1.0 - out["lpips"]
    out["n_samples"] = len(head)
    out["by_position"] = {
        p: {m: float(np.mean([r[m] for r in rows if r["position"] == p])) for m in METRICS}
        for p in sorted({r["position"] for r in rows})
    }
    out["by_zone"] = {
        z: {"n_samples": len(zr), **{m: float(np.mean([r[m] for r in zr])) for m in METRICS}}
        for z in ZONES
        if (zr := in_zone(head, z))
    }
    return out


def per_image(rows: list[dict], metric: str) -> dict[str, float]:
    vals: dict[str, list[float]] = {}
    for r in rows:
        vals.setdefault(r["image"], []).append(r[metric])
    return {k: float(np.mean(v)) for k, v in vals.items()}


def paired(a_rows: list[dict], b_rows: list[dict], n_boot: int = 2000, seed: int = 0) -> dict:
    """Mean of b - a per image and its 95 % bootstrap interval, for every metric, over the
    headline samples (``headline``: the frame positions where evaluated)."""
    a_rows, b_rows = headline(a_rows), headline(b_rows)
    where = [sorted((r["image"], r.get("position", "")) for r in rows) for rows in (a_rows, b_rows)]
    if where[0] != where[1]:
        raise InputError("paired comparison needs the same held-out images on both sides, at the same positions")
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
    """``paired`` restricted to each zone's headline samples (the same samples on both sides)."""
    a_rows, b_rows = headline(a_rows), headline(b_rows)
    return {z: paired(in_zone(a_rows, z), in_zone(b_rows, z), n_boot, seed) for z in ZONES if in_zone(a_rows, z)}


def paired_by_position(a_rows: list[dict], b_rows: list[dict], n_boot: int = 2000, seed: int = 0) -> dict:
    """``paired`` over each evaluated position's samples alone ("frame": each image's frame
    samples averaged; "centre", "corner": one sample per image), from the same rows."""
    present = {r["position"] for r in a_rows}
    order = [p for p in POSITION_ORDER if p in present] + sorted(present - set(POSITION_ORDER))
    return {p: paired(at_position(a_rows, p), at_position(b_rows, p), n_boot, seed) for p in order}
