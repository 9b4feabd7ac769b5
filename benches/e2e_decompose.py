#!/usr/bin/env python3
"""Which part of an end-to-end run helps or hurts: swap lens and processing between its two
cameras and measure the task loss on validation batches.

    python benches/e2e_decompose.py RUN_DIR [--val-seed 7] [--batches 8] [--json OUT.json]
    python benches/e2e_decompose.py RUN_DIR --heldout [--json OUT.json]

RUN_DIR is a finished `optix design` run. The lens is the nominal or the run's end-to-end
lens (through the surrogate, whatever optics the run trained on); the processing is the pre-trained one (Alg. 1's
start), the nominal baseline's or the end-to-end run's. Validation batches are the training
stream of another seed (procedural scenes, uniform positions over the frame, the task's light
levels, fixed noise): neither the batches training saw nor the held-out set, so a schedule
can be chosen on them. It measures; it asserts nothing.

``--heldout`` asks the same of the run's own evaluation instead: the two lenses under the
engine's exact PSFs, crossed with the two runs' processing (the hardware ISP: the reference ISP
at each run's hyperparameters), on the run's held-out set, with paired bootstrap intervals of
the lens's effect under each processing and of the processing's effect under each lens. The
diagonal is results.json's two cameras.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from optix_e2e.camera import Camera
from optix_e2e.camera_design.build import build_camera, load_surrogate
from optix_e2e.camera_design.config import DesignConfig, run_config
from optix_e2e.tasks import SensorFrame, TaskLoss, get_task, training_batch
from optix_e2e.torchfile import load_plain


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--val-seed", type=int, default=7)
    ap.add_argument("--batches", type=int, default=8)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--heldout",
        action="store_true",
        help="cross lens and processing on the held-out set, exact optics (paired intervals)",
    )
    a = ap.parse_args()
    run = Path(a.run)
    cfg = run_config(run).check()
    if a.val_seed == cfg.seed:
        raise SystemExit(f"--val-seed must differ from the run's seed {cfg.seed} (its training batches)")
    sur = load_surrogate(cfg.surrogate)
    task, frame = get_task(cfg.task), SensorFrame()
    loss = TaskLoss(task)
    e2e, nom, pre = (build_camera(cfg, sur) for _ in range(3))
    e2e.load_state_dict(load_plain(run / "end_to_end_state.pt", "design checkpoint")["camera"])
    st = load_plain(run / "nominal_state.pt", "design checkpoint")["camera"]
    nom.isp.load_state_dict({k[len("isp.") :]: v for k, v in st.items() if k.startswith("isp.")})
    for c in (e2e, nom, pre):
        c.eval()
    if a.heldout:
        return heldout_swap(run, cfg, sur, frame, nom, e2e, a.json)
    batches = [
        training_batch(a.val_seed, t, cfg.batch, cfg.crop, e2e.margin, (task.level_min, task.level_max), frame, None)
        for t in range(a.batches)
    ]

    @torch.no_grad()
    def val_loss(optics, isp) -> float:
        tot = 0.0
        for i, b in enumerate(batches):
            out, _ = Camera(optics, e2e.sensor, isp)(b.scene, b.offset_px, torch.Generator().manual_seed(100 + i))
            tot += float(loss(out, b.target)[0]) / len(batches)
        return tot

    rows = []
    for lens, optics in (("nominal", nom.optics), ("end_to_end", e2e.optics)):  # nom.optics: the nominal design
        for proc, isp in (("pretrained", pre.isp), ("nominal_run", nom.isp), ("end_to_end_run", e2e.isp)):
            rows.append({"lens": lens, "processing": proc, "val_loss": val_loss(optics, isp)})
            print(f"lens {lens:10s}  processing {proc:14s}  validation loss {rows[-1]['val_loss']:.4f}", flush=True)
    res = {
        "run": str(run),
        "task": cfg.task,
        "val_seed": a.val_seed,
        "batches": a.batches,
        "batch": cfg.batch,
        "crop": cfg.crop,
        "rows": rows,
    }
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))


def heldout_swap(run: Path, cfg: DesignConfig, sur, frame, nom, e2e, json_out) -> None:
    """Lens x processing on the held-out set under exact optics (see the module doc)."""
    from optix_e2e.camera import FixedOptics
    from optix_e2e.camera_design import evaluate as ev
    from optix_e2e.camera_design.build import design_field_heights
    from optix_e2e.surrogate.ground_truth import exact_optics
    from optix_e2e.tasks import heldout_set
    from optix_e2e.tasks.samples import POSITIONS

    values = torch.stack([nom.optics.base_values(), e2e.optics.values().detach()])
    exact = exact_optics(sur, values.double().numpy())
    samples = heldout_set(
        cfg.eval_size,
        exact["psf"].shape[-1] // 2,
        cfg.eval_procedural,
        cfg.eval_level,
        frame,
        positions=POSITIONS[cfg.eval_positions],
    )
    rows = {}
    for i, lens in enumerate(("nominal", "end_to_end")):
        heights = design_field_heights(sur, values[i].numpy(), exact["image_distance"][i])
        optics = FixedOptics(
            exact["psf"][i], exact["vignetting"][i], heights, patch=cfg.patch, full_field_px=frame.full_field_px
        )
        for proc, isp in (("nominal_run", nom.isp), ("end_to_end_run", e2e.isp)):
            rows[(lens, proc)] = ev.evaluate(Camera(optics, e2e.sensor, isp), samples)
            print(
                f"lens {lens:10s}  processing {proc:14s}  "
                + "  ".join(
                    f"{k} {v:.4f}"
                    for k, v in ev.summarize(rows[(lens, proc)]).items()
                    if k in ("psnr_db", "ssim", "lpips", "haarpsi")
                ),
                flush=True,
            )
    effects = {}
    for proc in ("nominal_run", "end_to_end_run"):  # the lens's effect, processing held
        effects[f"lens (processing {proc})"] = ev.paired(
            rows[("nominal", proc)], rows[("end_to_end", proc)], cfg.bootstrap, cfg.seed
        )
    for lens in ("nominal", "end_to_end"):  # the processing's effect, lens held
        effects[f"processing (lens {lens})"] = ev.paired(
            rows[(lens, "nominal_run")], rows[(lens, "end_to_end_run")], cfg.bootstrap, cfg.seed
        )
    for name, p in effects.items():
        print(
            f"{name:32s} "
            + "  ".join(f"{k} {v['mean']:+.4f} [{v['ci95'][0]:+.4f}, {v['ci95'][1]:+.4f}]" for k, v in p.items()),
            flush=True,
        )
    if json_out:
        Path(json_out).write_text(
            json.dumps(
                {
                    "run": str(run),
                    "task": cfg.task,
                    "n_samples": len(samples),
                    "cameras": {f"{lens}|{proc}": ev.summarize(r) for (lens, proc), r in rows.items()},
                    "effects": effects,
                },
                indent=2,
            )
        )


if __name__ == "__main__":
    main()
