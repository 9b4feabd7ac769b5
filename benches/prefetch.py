#!/usr/bin/env python3
"""The design run's training with its next batch made inline or beside the step.

    python benches/prefetch.py [--budget quick] [--reps 2] [--out DIR]

The main job's end-to-end training (``optix design iq-software``'s budget, its camera and
optimizer, exact optics by default) run whole on this machine's default device, alternating
inline and prefetched (tasks/prefetch.py; ``training.PREFETCH_ON_CPU`` forced on for the CPU),
``--reps`` times each: wall seconds per run, the final loss (the same both ways), and a warm
training batch's own time. Prints one JSON object (``--out`` also writes prefetch.json). It
measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", default="quick")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    if a.reps < 1:
        raise SystemExit(f"--reps must be >= 1, got {a.reps}")

    import torch

    from optix_e2e.camera_design import training
    from optix_e2e.camera_design.build import build_camera, load_surrogate, make_optimizer
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.tasks import SensorFrame, get_task, training_batch

    cfg = make_config(a.budget)
    sur, frame, task = load_surrogate(cfg.surrogate), SensorFrame(), get_task(cfg.task)
    margin = build_camera(cfg, sur, frame=frame).margin

    def batch(k):
        levels = (task.level_min, task.level_max)
        return training_batch(
            cfg.seed, k, cfg.batch, cfg.crop, margin, levels, frame, None, positions=cfg.train_positions
        )

    batch(0)  # warm: imports, caches
    t = time.perf_counter()
    for k in range(1, 11):
        batch(k)
    batch_ms = (time.perf_counter() - t) / 10 * 1e3
    runs = []
    for _ in range(a.reps):
        for ahead in (False, True):
            training.PREFETCH_ON_CPU = ahead
            torch.manual_seed(0)
            cam = build_camera(cfg, sur, frame=frame)
            opt = make_optimizer(cfg, cam, cfg.optimizer)
            with tempfile.TemporaryDirectory() as d:
                t = time.perf_counter()
                r = training.train(cfg, cam, opt, Path(d), "e2e", progress=False, frame=frame)
                runs.append(
                    {
                        "prefetch": ahead,
                        "seconds": time.perf_counter() - t,
                        "steps": r["steps"],
                        "final_loss": r["final_loss"],
                    }
                )
    res = {
        "budget": a.budget,
        "device": str(cam.device),
        "torch_threads": torch.get_num_threads(),
        "batch_ms_warm": batch_ms,
        "runs": runs,
    }
    print(json.dumps(res))
    if a.out:
        Path(a.out).mkdir(parents=True, exist_ok=True)
        (Path(a.out) / "prefetch.json").write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
