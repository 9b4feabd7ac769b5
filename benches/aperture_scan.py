#!/usr/bin/env python3
"""Where does a detection run's task point at its end? Its end-to-end lens with only the
aperture changed, behind its own end-to-end processing (hardware ISP and detector, fixed),
under the engine's exact PSFs (issue 35: does a run stop short of a faster lens its task
prefers, or where the task turns?).

    python benches/aperture_scan.py RUN --out DIR [--f-numbers 3.2 3.4 3.6 3.8 4.0 4.4]
                                    [--batches 48] [--scenes 100] [--threads N]

RUN is a finished `optix design detection` run. Each lens is the run's end-to-end lens with
its f-number set (the run's own f-number is always one of them), refocused and computed by
the engine as the run's evaluation computes it. Two measures, neither on the held-out set:

* the training loss (FCOS's focal + GIoU + centre-ness, what the run's optimizer follows) on
  ``--batches`` batches of a validation stream (street batches of seed 7, the run's crop and
  batch, a fixed noise stream per batch), each lens on the same batches and noise: per lens
  its mean and, against the run's own aperture, the paired mean difference with a Student's t
  interval over batches;
* mAP@0.5, mAP and dark-object mAP@0.5 on ``--scenes`` validation street scenes (made like the
  held-out ones, from other seeds: ``tasks.detection.VALIDATION_STREETS``), against the run's own
  aperture with a paired bootstrap interval over scenes (the run's bootstrap settings).

Each lens's manufacturability problems (the run's guard, the space's limits) are listed: a
faster aperture alone may break an edge limit the optimizer would have had to make room for.
Writes DIR/aperture_scan.json, DIR/aperture_scan.csv and DIR/aperture_scan.png. It measures;
it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from alg1_vs_vanilla import seeds_interval  # Student's t interval of a mean of paired differences
from detection_swap import camera_state, finished_run, load_processing

from optix_e2e.camera import FixedOptics
from optix_e2e.camera_design.build import design_field_heights, start_run
from optix_e2e.camera_design.config import DesignConfig
from optix_e2e.camera_design.detection import detection_scores, evaluate_detection, map_resamples, paired_resamples
from optix_e2e.camera_design.guard import Manufacturable
from optix_e2e.camera_design.run import hooks_for
from optix_e2e.camera_design.training import noise_generator
from optix_e2e.errors import InputError
from optix_e2e.io import claim_out_dir
from optix_e2e.parallel import Ranks
from optix_e2e.surrogate.ground_truth import exact_optics
from optix_e2e.tasks.detection import VALIDATION_STREETS, heldout_streets, street_batch

OUT_FILES = ("aperture_scan.json", "aperture_scan.csv", "aperture_scan.png")
VALIDATION_SEED = 7  # the validation stream's seed (benches/e2e_gradient_line.py's too); runs use 0, 1, 2


def validation_losses(cam, cfg: DesignConfig, task, frame, n: int) -> np.ndarray:
    """The camera's training loss on each of ``n`` validation batches (fixed noise per batch)."""
    out = []
    cam.train()  # FCOS returns its losses in training mode (GroupNorm: no running statistics)
    with torch.no_grad():
        for t in range(n):
            b = street_batch(
                VALIDATION_SEED, t, cfg.batch, cfg.crop_hw, cam.margin, (task.level_min, task.level_max), frame
            )
            loss, _ = cam(b.scene, b.offset_px, noise_generator(VALIDATION_SEED, t), b.targets)
            out.append(float(loss))
    cam.eval()
    return np.array(out)


def chart(path: Path, rows: list[dict], own: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = [r["f_number"] for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))

    def errorbars(axis, key: str, label: str) -> None:
        x = [r[key] for r in rows]
        # a bootstrap percentile interval need not hold the full sample's mean: no negative bars
        lo = [max(0.0, v["mean"] - v["ci95"][0]) for v in x]
        hi = [max(0.0, v["ci95"][1] - v["mean"]) for v in x]
        axis.errorbar(f, [v["mean"] for v in x], yerr=np.array([lo, hi]), marker="o", capsize=3)
        axis.set_ylabel(f"validation {label} - at the run's aperture")

    errorbars(ax[0], "loss_minus_own", "loss")
    if rows[0].get("map_50_minus_own"):
        errorbars(ax[1], "map_50_minus_own", "mAP@0.5")
    for a in ax:
        a.axhline(0, color="grey", lw=0.8)
        a.axvline(own, color="red", lw=0.8, ls="--")
        a.set_xlabel("f-number (the run's lens otherwise)")
        a.invert_xaxis()
    fig.suptitle("Aperture scan at the end of the run (95 % paired intervals; red: the run's own)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--f-numbers", type=float, nargs="+", default=[3.2, 3.4, 3.6, 3.8, 4.0, 4.4])
    ap.add_argument("--batches", type=int, default=48, help="validation batches for the loss (>= 2)")
    ap.add_argument("--scenes", type=int, default=100, help="validation scenes for mAP (0: none)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: the run's)")
    a = ap.parse_args(argv)
    if a.batches < 2 or a.scenes < 0:
        ap.error("--batches must be >= 2 and --scenes >= 0")
    try:  # its own files only: a folder holding anything else is refused before the work
        claim_out_dir(a.out, "aperture scan", writes=OUT_FILES, marker=OUT_FILES[0])
    except InputError as err:
        ap.error(str(err))
    cfg, res = finished_run(a.run)
    if a.threads is not None:
        try:
            cfg = DesignConfig(**{**cfg.to_json(), "threads": a.threads}).check()
        except InputError as err:
            ap.error(str(err))
    _, task, frame, sur = start_run(cfg, a.out)
    hooks = hooks_for(cfg, "cpu")
    hooks.check(sur, Ranks())
    base = np.asarray(res["design"]["end_to_end"], np.float64)
    own = float(base[hooks.f_index])
    f_numbers = sorted({round(f, 4) for f in a.f_numbers} | {own})
    values = np.repeat(base[None], len(f_numbers), 0)
    values[:, hooks.f_index] = f_numbers
    guard = Manufacturable(sur.manifest)
    t0 = time.perf_counter()
    try:
        exact = exact_optics(sur, values, fallback=hooks.exact_fallback)
    except InputError as err:  # an aperture the lens cannot pass (rays miss a surface)
        raise SystemExit(
            f"{a.run}: the engine cannot image its lens at f/{min(f_numbers):g}-{max(f_numbers):g}: {err}"
        ) from None
    print(f"exact PSFs of {len(f_numbers)} lenses: {time.perf_counter() - t0:.0f} s", flush=True)
    state = camera_state(a.run / "end_to_end_state.pt")
    samples = (
        heldout_streets(
            a.scenes,
            cfg.crop_hw,
            exact["psf"].shape[-1] // 2,
            (task.level_min, task.level_max),
            frame,
            start=VALIDATION_STREETS,
        )
        if a.scenes
        else []
    )
    losses, boots, scores = {}, {}, {}
    for i, f in enumerate(f_numbers):
        t0 = time.perf_counter()
        psf, vig = exact["psf"][i], exact["vignetting"][i]
        fh = design_field_heights(sur, values[i], exact["image_distance"][i])
        optics = FixedOptics(psf, vig, fh, patch=cfg.patch, full_field_px=frame.full_field_px, f_number=f)
        cam = load_processing(hooks, sur, frame, state, optics)
        losses[f] = validation_losses(cam, cfg, task, frame, a.batches)
        if samples:
            preds = evaluate_detection(cam, samples)
            scores[f] = detection_scores(preds, samples, task.dark)
            boots[f] = map_resamples(preds, samples, cfg.bootstrap, cfg.seed, task.dark)
        print(
            f"f/{f:.2f}: loss {losses[f].mean():.4f}"
            + (f", mAP@0.5 {scores[f]['map_50']:.3f}" if samples else "")
            + f" ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    rows = []
    for i, f in enumerate(f_numbers):
        d = losses[f] - losses[own]
        row = {
            "f_number": f,
            "own": f == own,
            "problems": guard.problems(values[i]),
            "psf_method": exact["methods"][i],
            "image_distance_mm": float(exact["image_distance"][i]),
            "loss": float(losses[f].mean()),
            "loss_minus_own": {"mean": float(d.mean()), "ci95": seeds_interval(list(d)) if f != own else [0.0, 0.0]},
        }
        if samples:
            p = paired_resamples(boots[own], boots[f])
            row |= {
                "map_50": scores[f]["map_50"],
                "map": scores[f]["map"],
                "dark_map_50": scores[f]["dark"]["map_50"],
                "map_50_minus_own": p["map_50"],
                "map_minus_own": p["map"],
                "dark_map_50_minus_own": p["dark"]["map_50"],
            }
        rows.append(row)
    out = {
        "run": str(a.run),
        "own_f_number": own,
        "validation": {"seed": VALIDATION_SEED, "batches": a.batches, "batch": cfg.batch, "scenes": a.scenes},
        "rows": rows,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "aperture_scan.json").write_text(json.dumps(out, indent=2))
    keys = ["f_number", "own", "loss", "loss_minus_own", "map_50", "map_50_minus_own", "dark_map_50_minus_own"]
    with open(a.out / "aperture_scan.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([*keys, "problems"])
        for r in rows:
            cells = []
            for k in keys:
                v = r.get(k, "")
                cells.append(
                    f"{v['mean']:+.4f} [{v['ci95'][0]:+.4f}, {v['ci95'][1]:+.4f}]" if isinstance(v, dict) else v
                )
            w.writerow([*cells, "; ".join(r["problems"])])
    chart(a.out / "aperture_scan.png", rows, own)
    print((a.out / "aperture_scan.csv").read_text())
    return out


if __name__ == "__main__":
    sys.exit(main() and 0)
