#!/usr/bin/env python3
"""Time of one end-to-end optimizer step, split by stage: surrogate (lens parameters -> PSFs),
render (overlap-add), sensor (EMVA, noise on), ISP, loss (L1 + LPIPS), backward, optimizer.

    python benches/design_step.py [--task iq-software] [--budget quick] [--steps 10] [--json]
                                  [--surrogate NAME] [--config FILE.toml]

Median milliseconds per stage over --steps steps (after 2 warm-up steps) with every block
learning (the fine-tuning phase: the most expensive step), at the budget's crop and batch.
It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch


def main() -> None:
    from optix_e2e.camera_design.build import build_camera, load_surrogate
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.metrics.lpips import LPIPS
    from optix_e2e.optics.render import render
    from optix_e2e.tasks import SensorFrame, get_task, task_loss, training_batch

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--budget", default="quick")
    ap.add_argument("--surrogate", default=None)
    ap.add_argument("--config", default=None)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    cfg = make_config(a.budget, a.config, task=a.task, surrogate=a.surrogate)
    task, frame = get_task(cfg.task), SensorFrame()
    cam = build_camera(cfg, load_surrogate(cfg.surrogate), frame=frame)
    lp = LPIPS()
    params = [p for ps in cam.blocks().values() for p in ps]
    opt = torch.optim.Adam(params, lr=1e-6)
    m = cam.margin
    times: dict[str, list[float]] = {
        k: [] for k in ("surrogate", "render", "sensor", "isp", "loss", "backward", "optimizer", "total")
    }
    for t in range(a.steps + 2):
        b = training_batch(cfg.seed, t, cfg.batch, cfg.crop, m, (task.level_min, task.level_max), frame)
        gen = torch.Generator().manual_seed(t)
        opt.zero_grad(set_to_none=True)
        c = [time.perf_counter()]
        psf, vig = cam.optics.psfs()
        c.append(time.perf_counter())
        img = render(
            b.scene,
            psf,
            cam.optics.fields,
            vig,
            patch=cfg.patch,
            full_field_px=frame.full_field_px,
            offset_px=b.offset_px,
        )[..., m:-m, m:-m]
        c.append(time.perf_counter())
        raw = cam.sensor(img, gen)
        c.append(time.perf_counter())
        out = cam.isp(raw, b.offset_px, frame.full_field_px)
        c.append(time.perf_counter())
        loss, _ = task_loss(out, b.target, lp, task.lpips_weight)
        c.append(time.perf_counter())
        loss.backward()
        c.append(time.perf_counter())
        opt.step()
        c.append(time.perf_counter())
        if t >= 2:
            for k, (x, y) in zip(list(times)[:-1], zip(c, c[1:])):
                times[k].append(1e3 * (y - x))
            times["total"].append(1e3 * (c[-1] - c[0]))
    res = {
        "task": cfg.task,
        "budget": cfg.budget,
        "crop": cfg.crop,
        "batch": cfg.batch,
        "psf_size": int(psf.shape[-1]),
        "threads": torch.get_num_threads(),
        "steps": a.steps,
        "median_ms": {k: round(float(np.median(v)), 1) for k, v in times.items()},
    }
    res["steps_per_s"] = round(1e3 / res["median_ms"]["total"], 2)
    if a.json:
        print(json.dumps(res))
    else:
        print(
            f"{cfg.task}, crop {cfg.crop}, batch {cfg.batch}, {res['threads']} threads: "
            + ", ".join(f"{k} {v} ms" for k, v in res["median_ms"].items())
        )


if __name__ == "__main__":
    main()
