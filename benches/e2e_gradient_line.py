#!/usr/bin/env python3
"""Does the surrogate's lens gradient lower the exact task loss? A line search from the
nominal lens along it, the loss under the surrogate's and the engine's PSFs.

    python benches/e2e_gradient_line.py [--task iq-software] [--batches 6] [--json OUT.json]

The processing is the pre-trained one (fixed), the batches a validation stream (seed 7, the
quick budget's crop and batch, fixed noise). Directions in the optimizer's coordinates (the
sigmoid-reparameterized lens parameters u): the unit negative gradient, and its sign (what
Adam's first steps follow); step sizes 0.01-0.3 in u. Not checked against the
manufacturability limits. It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from optix_e2e.camera import Camera, FixedOptics
from optix_e2e.camera_design.build import build_camera, design_field_heights, load_surrogate
from optix_e2e.camera_design.config import make_config
from optix_e2e.surrogate.ground_truth import exact_optics
from optix_e2e.tasks import SensorFrame, TaskLoss, get_task, training_batch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--batches", type=int, default=6)
    ap.add_argument("--steps", type=float, nargs="+", default=[0.0, 0.01, 0.03, 0.1, 0.3])
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    cfg = make_config("quick", task=a.task)
    sur = load_surrogate(cfg.surrogate)
    cam = build_camera(cfg, sur)
    cam.eval()
    task, frame = get_task(cfg.task), SensorFrame()
    loss = TaskLoss(task)
    batches = [
        training_batch(7, t, cfg.batch, cfg.crop, cam.margin, (task.level_min, task.level_max), frame, None)
        for t in range(a.batches)
    ]
    for p in cam.isp.parameters():
        p.requires_grad_(False)
    optics = cam.optics

    def task_loss(o, grad: bool = False) -> float:
        tot = 0.0
        for i, b in enumerate(batches):
            with torch.set_grad_enabled(grad):
                out, _ = Camera(o, cam.sensor, cam.isp)(b.scene, b.offset_px, torch.Generator().manual_seed(100 + i))
                val = loss(out, b.target)[0] / len(batches)
            if grad:
                val.backward()
            tot += float(val)
        return tot

    optics.u.grad = None
    task_loss(optics, grad=True)
    g = optics.u.grad.detach().clone()
    u0 = optics.u.detach().clone()
    rows = []
    for name, d in (("gradient", -g / g.norm()), ("sign", -torch.sign(g))):
        for step in a.steps:
            with torch.no_grad():
                optics.u.copy_(u0 + step * d)
            v = optics.values().detach()
            sur_loss = task_loss(optics)
            ex = exact_optics(sur, v[None].double().numpy())
            h = design_field_heights(sur, v.double().numpy(), ex["image_distance"][0])
            exact = FixedOptics(
                ex["psf"][0], ex["vignetting"][0], h, patch=cfg.patch, full_field_px=frame.full_field_px
            )
            rows.append({"direction": name, "step_u": step, "loss_surrogate": sur_loss, "loss_exact": task_loss(exact)})
            print(
                f"{name:8s} step {step:5.2f}  loss: surrogate optics {sur_loss:.4f}  exact optics "
                f"{rows[-1]['loss_exact']:.4f}",
                flush=True,
            )
    if a.json:
        Path(a.json).write_text(json.dumps({"task": a.task, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
