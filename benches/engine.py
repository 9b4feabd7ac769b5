#!/usr/bin/env python3
"""Speed of the engine through its Python bindings, on the bundled Cooke triplet.

    python benches/engine.py --json

prints one JSON object:
  rays_per_s      1e6 rays at full field (20 deg), 550 nm, paraxial aiming, via trace_field
  fft_psf_ms      one FFT PSF at full field, 64 pupil samples, fft_grid 256
  huygens_psf_ms  one Huygens PSF at full field, 64 pupil samples, 128 x 128 image
each the median of its runs after one warm-up (--repeats for the ray trace and the Huygens
PSF; sub-millisecond FFT PSFs get --fft-repeats, since a 2-core VM's scheduling noise is
of the same order), plus the minima, the machine and the settings.
This measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from optix_e2e.lens import Lens


def median_time(fn, repeats: int) -> tuple[float, list[float]]:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def pupil_points(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n points uniformly distributed over the unit pupil disc."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.random(n))
    t = 2 * np.pi * rng.random(n)
    return r * np.cos(t), r * np.sin(t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="print one JSON object (default: a readable list)")
    ap.add_argument("--lens", default="cooke-f50")
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--fft-repeats", type=int, default=200)
    ap.add_argument("--wavelength-nm", type=float, default=550.0)
    args = ap.parse_args()

    lens = Lens.load(args.lens)
    field = lens.max_field_deg
    wl = args.wavelength_nm
    px, py = pupil_points(args.rays)

    def trace():
        lens.trace_field(field, px, py, wl)

    def fft():
        lens.psf(field, wl, "fft", pixel_um=1.0, size=64, pupil_samples=64, fft_grid=256)

    def huygens():
        lens.psf(field, wl, "huygens", pixel_um=0.5, size=128, pupil_samples=64)

    t_trace, trace_all = median_time(trace, args.repeats)
    t_fft, fft_all = median_time(fft, args.fft_repeats)
    t_huy, huy_all = median_time(huygens, max(3, args.repeats // 2))
    n_ok = int(np.count_nonzero(lens.trace_field(field, px, py, wl)["status"] == 0))

    from optix_e2e import _engine

    result = {
        "lens": lens.name,
        "rays_per_s": args.rays / t_trace,
        "fft_psf_ms": t_fft * 1e3,
        "huygens_psf_ms": t_huy * 1e3,
        "settings": {
            "rays": args.rays,
            "rays_ok": n_ok,
            "field_deg": field,
            "wavelength_nm": wl,
            "aiming": "paraxial",
            "fft": {"pupil_samples": 64, "fft_grid": 256, "size": 64, "pixel_um": 1.0},
            "huygens": {"pupil_samples": 64, "size": 128, "pixel_um": 0.5},
            "statistic": "median",
            "repeats": args.repeats,
            "fft_repeats": args.fft_repeats,
        },
        "min_s": {"trace": min(trace_all), "fft": min(fft_all), "huygens": min(huy_all)},
        "samples_s": {"trace": trace_all, "huygens": huy_all},
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "engine_version": getattr(_engine, "__version__", None),
            "simd": getattr(_engine, "simd", None),
        },
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"{lens.name}: {result['rays_per_s'] / 1e6:.2f} M rays/s, FFT PSF {result['fft_psf_ms']:.3f} ms, "
            f"Huygens PSF {result['huygens_psf_ms']:.1f} ms (medians of {args.repeats} / {args.fft_repeats} / "
            f"{max(3, args.repeats // 2)} runs; kernel {result['machine']['simd']})"
        )


if __name__ == "__main__":
    main()
