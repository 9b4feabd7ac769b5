#!/usr/bin/env python3
"""How much of each PSF a smaller sensor-pitch window would cut: for a PSF dataset, the
energy outside the central W x W pixels of its sensor-pitch PSFs, per field.

    python benches/psf_window_energy.py DATA [--windows 21 25 31 41]

Prints, per window, the median and 90th percentile over designs (worst channel) of the
fraction of the stored window's energy that lies outside the central W x W, per field, and
the fraction of designs losing more than 1 % at some field; and the range of the stored
window's own sums (the engine's flux fraction inside it). docs/e2e.md quotes it for the
paper-triplet-e2e space. It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import glob
import json

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--windows", type=int, nargs="+", default=[21, 25, 31, 41])
    ap.add_argument("--max-shards", type=int, default=32)
    a = ap.parse_args()
    files = sorted(glob.glob(f"{a.data}/shards/*/psf_sensor.npy"))[: a.max_shards]
    psf = np.concatenate([np.load(f) for f in files])  # [N, K, C, S, S]
    s, c = psf.shape[-1], psf.shape[-1] // 2
    tot = psf.sum((-2, -1))
    out = {
        "data": a.data,
        "n_designs": int(psf.shape[0]),
        "window_px": int(s),
        "stored_sum_range": [float(tot.min()), float(tot.max())],
        "windows": {},
    }
    for w in a.windows:
        if w > s:
            continue
        h = w // 2
        lost = (1 - psf[..., c - h : c + h + 1, c - h : c + h + 1].sum((-2, -1)) / tot).max(-1)  # worst channel
        out["windows"][w] = {
            "median_per_field": np.round(np.median(lost, 0), 4).tolist(),
            "p90_per_field": np.round(np.percentile(lost, 90, 0), 4).tolist(),
            "frac_designs_over_1pct": float((lost.max(1) > 0.01).mean()),
        }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
