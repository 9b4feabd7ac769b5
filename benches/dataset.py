#!/usr/bin/env python3
"""Dataset generation speed: designs per second for a bundled space at the default
settings (13 fields x RGB, 128 um window at 1 um, sensor-pitch copy, FFT PSFs).

    python benches/dataset.py [--space paper-triplet] [-n 2048] [--json]

Runs ``optix_e2e.dataset.generate`` into a temporary directory and prints one JSON object:
designs_per_s (refocusing, PSF computation and shard writing; the up-front sampling is
timed apart as sampling_s), engine_designs_per_s (the engine's psf_batch alone on the same
refocused designs, 16 per call), n, n_failed, seconds, the settings and the machine.  It measures; it asserts
nothing.  For comparison, the issue quotes optiland 0.6.3 at about 0.87 s per design for
13 fields x 3 wavelengths of FFT PSFs on this 2-core machine (1.15 designs/s).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from dataclasses import asdict

from optix_e2e.dataset import DatasetSettings, generate
from optix_e2e.dataset.manifest import prepare
from optix_e2e.lens_design.space import load_space


def engine_only(root: str) -> float:
    """psf_batch alone over the dataset's refocused designs (16 per call, into one reused
    buffer with the sensor-pixel copy, as the generator calls it)."""
    from pathlib import Path

    import numpy as np

    from optix_e2e import _engine
    from optix_e2e.dataset.layout import read_manifest
    from optix_e2e.dataset.manifest import refocused_designs

    man = read_manifest(root)
    s = DatasetSettings.of_manifest(man["settings"])
    jsons = []
    for d in sorted((Path(root) / "shards").iterdir()):
        designs = refocused_designs(man, np.load(d / "params.npy"), np.load(d / "image_distance.npy"))
        jsons += [json.dumps(lens) for lens in designs]
    channels = [[tuple(p) for p in c] for c in man["channels"]]
    lead = (16, len(man["fields_deg"]), len(channels))
    psf = np.zeros(lead + (s.size, s.size), np.float32)
    sensor = np.zeros(lead + (s.sensor_size, s.sensor_size), np.float32)
    t = time.perf_counter()
    for i in range(0, len(jsons), 16):
        m = len(jsons[i : i + 16])
        _engine.psf_batch(
            jsons[i : i + 16],
            man["fields_deg"],
            channels,
            s.psf_method,
            s.pixel_um,
            s.size,
            s.pupil_samples,
            s.aiming,
            False,
            True,
            psf[:m],
            (s.sensor_pixel_um, s.sensor_size),
            sensor[:m],
        )
    return len(jsons) / (time.perf_counter() - t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet")
    ap.add_argument("-n", type=int, default=2048)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pupil-samples", type=int, default=DatasetSettings.pupil_samples)
    ap.add_argument("--json", action="store_true", help="print only the JSON object")
    a = ap.parse_args()
    s = DatasetSettings(pupil_samples=a.pupil_samples)
    with tempfile.TemporaryDirectory() as tmp:
        space, base = load_space(a.space)
        t = time.perf_counter()
        prepare(__import__("pathlib").Path(tmp), space, base, a.n, a.seed, s)
        sampling_s = time.perf_counter() - t
        rep = generate(a.space, a.n, a.seed, tmp, s, progress=not a.json)
        engine_rate = engine_only(tmp)
    out = {
        "space": a.space,
        "n": a.n,
        "n_failed": rep.n_failed,
        "seconds": rep.seconds,
        "designs_per_s": rep.designs_per_s,
        "engine_designs_per_s": engine_rate,
        "sampling_s": sampling_s,
        "settings": asdict(s),
        "machine": {
            "cpus": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
            "rayon_threads": os.environ.get("RAYON_NUM_THREADS", "all"),
        },
    }
    print(json.dumps(out, indent=None if a.json else 2))


if __name__ == "__main__":
    main()
