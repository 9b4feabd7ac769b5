#!/usr/bin/env python3
"""What a design run's training takes in memory, measured, and the model the run checks itself
against before it starts (camera_design/memory.py, python/optix_e2e/bundled/design/memory_model.json):

    python benches/memory_model.py [--out benches/results/memory_model] [--write-model]

For each task and a few (crop, batch) settings, runs `optix design TASK --budget smoke` (its
schedule, exact optics as the task's smoke budget has them, one torch thread) in a process of its
own and reads that process's peak resident memory (ru_maxrss). Fits, per task, peak = base +
per_pixel x batch x (crop + 2 m) x (crop_width + 2 m), m the camera's margin (the PSF's
half-window: the scene a step renders), by least squares, and reports each setting's measured and
modelled peak. --write-model writes the fit (with this command and the date) to the bundled model.
It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))

from optix_e2e.io import write_record_atomic  # noqa: E402

#: (crop, crop_width, batch) per task: from the smoke size to a few times the quick budget's pixels
SETTINGS = {
    "iq-software": [(64, 0, 1), (128, 0, 2), (256, 0, 2), (256, 0, 4)],
    "iq-hardware": [(64, 0, 1), (128, 0, 2), (256, 0, 2), (256, 0, 4)],
    "detection": [(64, 96, 1), (128, 192, 2), (192, 288, 2), (192, 288, 4)],
}

CHILD = """
import json, resource, sys
from pathlib import Path
from optix_e2e.camera_design.config import make_config
from optix_e2e.camera_design.run import hooks_for
from optix_e2e.camera_design.build import start_run
task, crop, width, batch, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
cfg = make_config("smoke", task=task, crop=crop, crop_width=width, batch=batch, threads=1, n_cycles=1,
                  steps_optics=2, steps_isp=2, n_finetune=0, eval_size=32, eval_procedural=0,
                  **({"steps_detector": 2, "eval_scenes": 1} if task == "detection" else {}))
from optix_e2e.camera_design.run import run_design
_, _, frame, sur = start_run(cfg, out)
margin = hooks_for(cfg).build_camera(sur, frame).margin
run_design(cfg, Path(out), progress=False, log=lambda *a: None)
print(json.dumps({"peak_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, "margin": margin}))
"""


def measure(task: str, crop: int, width: int, batch: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run(
            [sys.executable, "-c", CHILD, task, str(crop), str(width), str(batch), str(Path(tmp) / "run")],
            capture_output=True,
            text=True,
            env={"PYTHONPATH": str(ROOT / "python"), "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1"},
        )
    if r.returncode:
        raise SystemExit(f"{task} crop {crop}x{width or crop} batch {batch}: {r.stderr.strip().splitlines()[-1]}")
    got = json.loads(r.stdout.strip().splitlines()[-1])
    m = got["margin"]
    px = batch * (crop + 2 * m) * ((width or crop) + 2 * m)
    return {"task": task, "crop": crop, "crop_width": width, "batch": batch, "margin": m, "pixels": px, **got}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benches" / "results" / "memory_model")
    ap.add_argument("--tasks", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--write-model", action="store_true")
    a = ap.parse_args(argv)
    rows, model = [], {}
    for task in a.tasks:
        got = [measure(task, *s) for s in SETTINGS[task]]
        for g in got:
            print(
                f"{task} crop {g['crop']}x{g['crop_width'] or g['crop']} batch {g['batch']}: {g['peak_bytes'] / 1e9:.2f} GB"
            )
        x = np.array([[1.0, g["pixels"]] for g in got])
        y = np.array([g["peak_bytes"] for g in got], float)
        (base, per_px), *_ = np.linalg.lstsq(x, y, rcond=None)
        model[task] = {"base_bytes": float(base), "bytes_per_pixel": float(per_px)}
        for g in got:
            g["modelled_bytes"] = float(base + per_px * g["pixels"])
            g["model_error"] = g["modelled_bytes"] / g["peak_bytes"] - 1
        rows += got
    doc = {
        "command": "python benches/memory_model.py --write-model",
        "date": datetime.date.today().isoformat(),
        "peak": "ru_maxrss of a smoke design run (train, evaluate, outputs) at each setting, one torch thread",
        "model": model,
        "rows": rows,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    write_record_atomic(a.out / "memory_model.json", doc)
    if a.write_model:
        from optix_e2e.camera_design.memory import MODEL_FILE

        write_record_atomic(MODEL_FILE, {k: doc[k] for k in ("command", "date", "peak", "model")})
    return doc


if __name__ == "__main__":
    main()
