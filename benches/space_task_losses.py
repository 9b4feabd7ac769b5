#!/usr/bin/env python3
"""Does the end-to-end space hold designs that beat the nominal on each task? Random designs
of the space, their exact PSFs from the engine, the task loss with the processing fixed.

    python benches/space_task_losses.py DATA [-n 300] [--tasks ...] [--scenes 6] [--size 96]
                                        [--out runs/space_losses]

DATA is a PSF dataset of the space (e.g. the surrogate's test set, data/e2e/test: Sobol'
designs within the space's manufacturability limits, refocused, sensor-pitch PSFs from the
engine). For its first n designs and the nominal (computed the same way): the PSFs rendered
onto a fixed set of procedural scenes at the sensor's centre and corner, through the sensor
(noise on, fixed seeds) and the fixed processing of each task (the bundled software ISP; for
iq-hardware the reference ISP at its default hyperparameters), scored with the task loss
(L1 + w LPIPS against the ideal rendering). Writes OUT/losses.csv (design, task, loss) and
OUT/summary.json: per task the nominal's loss, the fraction of designs below it, the best
design's loss and parameters. It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm


class FixedProcessing:
    """Each task's processing held fixed: the shipped software ISP, or for a hardware-ISP task
    the reference ISP at its default hyperparameters; the LPIPS network; the sensor preset at
    the base lens's f-number."""

    def __init__(self, f_number: float):
        from optix_e2e.camera_design.build import SOFTWARE_ISP
        from optix_e2e.isp.software import SoftwareISP
        from optix_e2e.metrics.lpips import LPIPS

        self.f_number, self.lp, self.isp_sw = f_number, LPIPS(), SoftwareISP.load(SOFTWARE_ISP)

    def hardware(self):
        from optix_e2e.isp import params as hp
        from optix_e2e.isp.reference import ReferenceISP

        ref = ReferenceISP()

        class DefaultHW(torch.nn.Module):  # the reference ISP at its default hyperparameters
            def forward(self, raw, *where):  # the crop's position is not used
                return ref(raw, [hp.defaults()] * raw.shape[0])

            final = forward

        return DefaultHW()

    @torch.no_grad()
    def loss(self, optics, task_name: str, samples) -> float:
        """The task loss (L1 + w LPIPS against the ideal rendering) of the camera with ``optics``
        (a FixedOptics) over held-out ``samples``, sensor noise from each sample's seed."""
        from optix_e2e.camera import Camera, SensorStage, SoftwareISPStage, calibrated_preset
        from optix_e2e.tasks import get_task, task_loss

        task = get_task(task_name)
        preset = calibrated_preset("imx249", self.f_number, task.exposure_factor, task.gain_factor)
        isp = SoftwareISPStage(self.isp_sw, preset) if task.isp == "software" else self.hardware()
        cam = Camera(optics, SensorStage(preset), isp)
        losses = []
        for smp in samples:
            o, _ = cam(smp.scene[None], smp.offset_px, torch.Generator().manual_seed(smp.noise_seed), final=True)
            losses.append(float(task_loss(o.clamp(0, 1), smp.target[None], self.lp, task.lpips_weight)[0]))
        return float(np.mean(losses))


def main() -> None:
    from optix_e2e.camera import FixedOptics
    from optix_e2e.camera.stages import image_height_fractions
    from optix_e2e.camera_design.outputs import design_lens
    from optix_e2e.dataset.layout import read_manifest
    from optix_e2e.dataset.manifest import space_and_base
    from optix_e2e.surrogate.ground_truth import exact_arrays
    from optix_e2e.tasks import SensorFrame, heldout_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("-n", type=int, default=300)
    ap.add_argument("--tasks", nargs="+", default=["iq-software", "iq-hardware", "low-light"])
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--out", default="runs/space_losses")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    man = read_manifest(a.data)
    space, base = space_and_base(man)
    nominal = np.asarray(space.values(base.data))[None]
    nom, meta = exact_arrays(man, nominal)
    psfs, vigs, values = [nom["psf_sensor"][0]], [nom["relative_illumination"][0]], [nominal[0]]
    zs = [float(nom["image_distance"][0])]
    for shard in sorted((Path(a.data) / "shards").iterdir()):
        if len(values) > a.n:
            break
        psfs += list(np.load(shard / "psf_sensor.npy"))
        vigs += list(np.load(shard / "relative_illumination.npy"))
        values += list(np.load(shard / "params.npy"))
        zs += list(np.load(shard / "image_distance.npy"))
    psfs, vigs, values = psfs[: a.n + 1], vigs[: a.n + 1], np.asarray(values[: a.n + 1])
    fields = man["fields_deg"]
    frame = SensorFrame()
    fixed = FixedProcessing(float(base.paraxial()["f_number"]))
    rows = []
    for i in tqdm(range(len(values)), desc="designs", unit="design"):
        psf = torch.as_tensor(psfs[i]).float()
        vig = torch.as_tensor(vigs[i]).float()
        # each design's fields where its chief rays land (its own distortion)
        heights = image_height_fractions(design_lens(man, values[i], zs[i]), fields)
        fo = FixedOptics(psf, vig, heights, full_field_px=frame.full_field_px)
        samples = heldout_set(a.size, psf.shape[-1] // 2, a.scenes, photos=[])
        for name in a.tasks:
            rows.append({"design": i, "task": name, "loss": fixed.loss(fo, name, samples)})
    with open(out / "losses.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["design", "task", "loss"])
        w.writeheader()
        w.writerows(rows)
    summary = {"data": a.data, "n_designs": int(len(values) - 1), "design_0": "the nominal", "tasks": {}}
    for name in a.tasks:
        r = {x["design"]: x["loss"] for x in rows if x["task"] == name}
        nominal = r.get(0)
        others = np.array([v for k, v in r.items() if k != 0])
        best = min((k for k in r if k != 0), key=r.get)
        summary["tasks"][name] = {
            "nominal_loss": nominal,
            "n": int(len(others)),
            "fraction_below_nominal": float((others < nominal).mean()),
            "median_loss": float(np.median(others)),
            "best_loss": r[best],
            "best_design": dict(zip(space.names, map(float, values[best]))),
        }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({t: {k: v for k, v in s.items() if k != "best_design"} for t, s in summary["tasks"].items()}))


if __name__ == "__main__":
    main()
