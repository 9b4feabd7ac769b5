#!/usr/bin/env python3
"""Dataset generation speed, where its time goes, and optiland's rate on the same machine.

    python benches/dataset.py [--space paper-triplet] [-n 600] [--optiland] [--json] [--out DIR]

Three measurements, one after the other on the same machine (run it on a quiet one):

1. **Whole command, start-up included**: ``optix dataset SPACE -n N`` as a fresh process
   (imports, sampling, refocusing, PSFs, shards written and checksummed), wall time;
   ``designs_per_s_end_to_end`` = N over it.
2. **Phases**, the same generation in this process with timers around each stage: importing
   the package (a fresh interpreter, ``import optix_e2e.cli``; the command loads no scipy.stats:
   its Sobol' points are lens_design/sobol.py's), sampling (``prepare``: the checked draws and the manifest), the
   refocus (``refocus_many``), the engine's ``psf_batch`` and the rest of ``generate`` (the
   geometry checks, shard writing, checksums); and ``engine_designs_per_s``, ``psf_batch``
   alone on the refocused designs (16 per call) as the generator calls it.
3. With ``--optiland`` (``pip install optiland==0.6.3``; not a project dependency): optiland's
   ``FFTPSF`` on its own Cooke triplet sample, one design = 13 fields x 3 wavelengths (0.48,
   0.55, 0.65 um) at 64 pupil samples on a 256 grid (the engine's settings), in a fresh
   process: ``startup_s`` (import, lens, numba's compilation and the first design) and
   ``s_per_design`` over ``--optiland-designs`` more designs. Two ratios: against its steady
   per-design rate (``ratio_per_design``, the strict one), and against its time for the same
   N designs start-up included (``ratio_same_n``: startup + (N - 1) x s_per_design).

Prints one JSON object (``--out`` also writes dataset_speed.json). It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

OPTILAND_SCRIPT = r"""
import json, sys, time, warnings
N = int(sys.argv[1])
t0 = time.perf_counter()
warnings.filterwarnings("ignore")
import numpy as np
from optiland.samples.objectives import CookeTriplet
from optiland.psf import FFTPSF
lens = CookeTriplet()
def design():
    for hy in np.linspace(0.0, 1.0, 13):
        for wl in (0.48, 0.55, 0.65):
            FFTPSF(lens, (0.0, float(hy)), wl, num_rays=64, grid_size=256)
design()
startup = time.perf_counter() - t0
t = time.perf_counter()
for _ in range(N):
    design()
print(json.dumps({"startup_s": startup, "s_per_design": (time.perf_counter() - t) / N, "designs": N}))
"""


@contextlib.contextmanager
def _timed(module, name: str, acc: dict, key: str):
    """Within the block, ``module.name`` is wrapped so that its wall time adds up in
    ``acc[key]``; restored after it (a caller in the same process, a test, sees the original)."""
    fn = getattr(module, name)

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] = acc.get(key, 0.0) + time.perf_counter() - t

    setattr(module, name, wrapper)
    try:
        yield
    finally:
        setattr(module, name, fn)


def engine_only(root: str) -> float:
    """psf_batch alone over the dataset's refocused designs (16 per call, into one reused
    buffer with the sensor-pixel copy, as the generator calls it)."""
    import numpy as np

    from optix_e2e import _engine
    from optix_e2e.dataset import DatasetSettings
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
            s.accuracy,
        )
    return len(jsons) / (time.perf_counter() - t)


def whole_command(space: str, n: int, seed: int) -> dict:
    """``optix dataset`` as a fresh process, start-up included."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", "from optix_e2e.cli import main; main()", "dataset", space, "-n", str(n)]
        cmd += ["--seed", str(seed), "--out", str(Path(tmp) / "ds")]
        t = time.perf_counter()
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        wall = time.perf_counter() - t
    if done.returncode:  # the command's own one-line refusal (a bad space, n, ...)
        raise SystemExit((done.stderr.strip().splitlines() or ["optix dataset failed"])[-1])
    return {"seconds": wall, "designs_per_s_end_to_end": n / wall}


def phases(space_name: str, n: int, seed: int, s) -> dict:
    """The generation in this process, each stage timed (see the module's docstring)."""
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import optix_e2e.cli"], check=True)
    import_s = time.perf_counter() - t
    from optix_e2e import engine
    from optix_e2e.dataset import generate, shards
    from optix_e2e.dataset.manifest import prepare
    from optix_e2e.lens_design.space import load_space

    acc: dict = {}
    with (
        _timed(shards, "refocus_many", acc, "refocus_s"),
        _timed(engine, "psf_batch", acc, "psf_batch_s"),
        tempfile.TemporaryDirectory() as tmp,
    ):
        space, base = load_space(space_name)
        t = time.perf_counter()
        prepare(Path(tmp), space, base, n, seed, s)
        sampling_s = time.perf_counter() - t
        rep = generate(space_name, n, seed, tmp, s, progress=False)
        engine_rate = engine_only(tmp)
    rest = rep.seconds - acc.get("refocus_s", 0.0) - acc.get("psf_batch_s", 0.0)
    return {
        "import_package_s": import_s,
        "sampling_s": sampling_s,
        "refocus_s": acc.get("refocus_s", 0.0),
        "psf_batch_s": acc.get("psf_batch_s", 0.0),
        "generate_rest_s": rest,
        "generate_s": rep.seconds,
        "designs_per_s_generate": rep.designs_per_s,
        "engine_designs_per_s": engine_rate,
        "n_failed": rep.n_failed,
    }


def optiland(designs: int) -> dict:
    try:
        cmd = [sys.executable, "-c", OPTILAND_SCRIPT, str(designs)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    except subprocess.CalledProcessError as err:
        tail = (err.stderr or "").strip().splitlines()[-1:] or ["no message"]
        return {"error": f"optiland could not run: {tail[0]}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict:
    from optix_e2e.dataset import DatasetSettings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet")
    ap.add_argument("-n", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pupil-samples", type=int, default=DatasetSettings.pupil_samples)
    ap.add_argument("--optiland", action="store_true", help="time optiland 0.6.3 too (must be installed)")
    ap.add_argument("--optiland-designs", type=int, default=3)
    ap.add_argument("--json", action="store_true", help="print the JSON object on one line")
    ap.add_argument("--out", type=Path, default=None, help="also write DIR/dataset_speed.json")
    a = ap.parse_args(argv)
    s = DatasetSettings(pupil_samples=a.pupil_samples)
    out: dict = {"space": a.space, "n": a.n, "seed": a.seed, "settings": asdict(s)}
    out["whole_command"] = whole_command(a.space, a.n, a.seed)
    out["phases"] = phases(a.space, a.n, a.seed, s)
    if a.optiland:
        o = optiland(a.optiland_designs)
        if "error" not in o:
            ours = out["whole_command"]["designs_per_s_end_to_end"]
            same_n = o["startup_s"] + (a.n - 1) * o["s_per_design"]
            o["designs_per_s"] = 1.0 / o["s_per_design"]
            o["ratio_per_design"] = ours * o["s_per_design"]
            o["ratio_same_n"] = same_n / out["whole_command"]["seconds"]
        out["optiland"] = o
    out["machine"] = {
        "cpus": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "rayon_threads": os.environ.get("RAYON_NUM_THREADS", "all"),
    }
    text = json.dumps(out, indent=None if a.json else 2)
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "dataset_speed.json").write_text(text + "\n")
    print(text)
    return out


if __name__ == "__main__":
    main()
