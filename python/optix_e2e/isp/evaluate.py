"""Proxy fidelity on held-out data: bundled photos (never used in training, which sees only
procedural scenes) captured by the simulated sensor, under hyperparameters drawn with a seed
the training never uses, plus the default hyperparameters. Metrics compare the proxy's output
with the true reference ISP's output (PSNR, SSIM, HaarPSI; ``crop`` border pixels left out)."""

from __future__ import annotations

import time

import numpy as np
import torch
from tqdm import tqdm

from .. import scenes
from ..errors import InputError
from ..metrics import image as metrics
from . import data
from . import params as hp
from .proxy import ISPProxy

HELD_OUT_SEED = 20_261_121  # hyperparameter draws and sensor noise for evaluation


def held_out_captures(
    size: int = 256, photos: list[str] | None = None, seed: int = HELD_OUT_SEED, capture: data.Capture = data.Capture()
):
    """(names, RAW [N, 1, size, size], ideal renderings [N, 3, size, size]) for the bundled photos."""
    names = photos or scenes.bundled_photos()
    imgs = torch.stack([scenes.load_photo(n, size=size) for n in names])
    rng = np.random.default_rng(seed)
    raw, ideal = data.capture_raw(imgs, rng, capture, torch.Generator().manual_seed(seed))
    return names, raw, ideal


@torch.no_grad()
def evaluate_proxy(
    proxy: ISPProxy,
    *,
    size: int = 256,
    n_param_sets: int = 4,
    crop: int = 4,
    photos: list[str] | None = None,
    seed: int = HELD_OUT_SEED,
    progress: bool = True,
) -> dict:
    proxy.eval()
    isp = data.reference_isp()
    names, raw, _ = held_out_captures(size, photos, seed)
    rng = np.random.default_rng(seed + 1)
    settings = [("default", hp.defaults())] + [(f"random{k}", hp.sample(rng)) for k in range(n_param_sets)]
    rows, t_ref, t_proxy = [], 0.0, 0.0
    for i, name in enumerate(tqdm(names, desc="eval proxy", unit="photo", disable=not progress)):
        for label, p in settings:
            t0 = time.perf_counter()
            truth = isp(raw[i : i + 1], [p])
            t1 = time.perf_counter()
            dev = next(proxy.parameters()).device  # the captures and truth stay on the CPU
            pred = proxy.render(raw[i : i + 1].to(dev), p).cpu()
            if not torch.isfinite(pred).all():
                raise InputError(
                    f"the ISP proxy's output is not finite on photo {name} ({label} hyperparameters); no metrics"
                )
            pred = pred.clamp(0, 1)
            t_ref, t_proxy = t_ref + t1 - t0, t_proxy + time.perf_counter() - t1
            s = metrics.summarize(pred, truth, crop=crop)
            rows.append({"photo": name, "params": label, **s})

    def mean(key, subset=rows):
        return float(np.mean([r[key] for r in subset]))

    random_rows = [r for r in rows if r["params"] != "default"]
    default_rows = [r for r in rows if r["params"] == "default"]
    return {
        "proxy_psnr_db": mean("psnr_db"),
        "proxy_ssim": mean("ssim"),
        "proxy_haarpsi": mean("haarpsi"),
        "min_psnr_db": float(min(r["psnr_db"] for r in rows)),
        "random_params": (
            {"psnr_db": mean("psnr_db", random_rows), "ssim": mean("ssim", random_rows)} if random_rows else None
        ),
        "default_params": {"psnr_db": mean("psnr_db", default_rows), "ssim": mean("ssim", default_rows)},
        "ms_per_image": {
            "reference_isp": 1e3 * t_ref / len(rows),
            "proxy": 1e3 * t_proxy / len(rows),
            "torch_threads": torch.get_num_threads(),
        },
        "n_photos": len(names),
        "n_param_sets": len(settings),
        "image_size": size,
        "crop_px": crop,
        "seed": seed,
        "photos": names,
        "per_case": rows,
    }
