#!/usr/bin/env python3
"""What the paper-width space holds (issue 34 step 2): random designs of a space, their RMS spots,
and, in boxes around the nominal, their exact PSFs and task losses with the processing fixed.

    python benches/wide_space_survey.py [--space paper-triplet-wide] [-n 300] [--boxes 0.05 0.1 0.2]
                                        [--per-box 40] [--tasks iq-software low-light] [--out runs/wide_survey]

1. ``-n`` designs drawn uniformly (Sobol') from the whole space, each manufacturable under the one
   constraint definition (lens_design/constraints.py) and refocused to its best focus: the
   polychromatic RMS spot at 0, half and the full field, against the nominal's.
2. In boxes of ``--boxes`` times each parameter's half-range about the nominal (clipped to the
   space), ``--per-box`` manufacturable designs each: their exact PSFs from the engine on the
   end-to-end surrogate's terms (its fields, 246 um window, PSF method ``auto``; the terms a
   design run's exact optics use), scored as benches/space_task_losses.py scores a dataset's:
   procedural scenes at the sensor's centre and corner, sensor noise on (fixed seeds), each
   task's fixed processing, the task loss (L1 + w LPIPS against the ideal rendering). A design
   whose PSF spills out of the window (energy in window < 0.9 at some field) is counted apart.

Writes OUT/spots.csv, OUT/losses.csv and OUT/summary.json; prints the summary. It measures; it
asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm


def spots_um(man: dict, values: np.ndarray, fields: list[float]) -> np.ndarray:
    """[N, F] polychromatic RMS spot (um) of refocused designs (inf where the engine fails)."""
    from optix_e2e.dataset.manifest import space_and_base
    from optix_e2e.lens import Lens
    from optix_e2e.lens.apertures import engine_base
    from optix_e2e.lens_design.focus import refocus_many

    space, base = space_and_base(man)
    lenses = [space.apply(engine_base(base, man["settings"]["apertures"]), v) for v in values]
    errors = refocus_many(lenses, "best", base.fields_deg, base.wavelengths_nm, base.wavelength_weights)
    out = np.full((len(values), len(fields)), np.inf)
    for i, (d, err) in enumerate(zip(lenses, errors)):
        if err is None:
            lens = Lens(d)
            out[i] = [lens.spot(f)["rms_um"] for f in fields]
    return out


def main() -> None:
    from optix_e2e.camera import FixedOptics
    from optix_e2e.camera.stages import image_height_fractions
    from optix_e2e.camera_design.build import load_surrogate
    from optix_e2e.camera_design.outputs import design_lens
    from optix_e2e.lens_design.constraints import Limits
    from optix_e2e.lens_design.sampling import sample_designs
    from optix_e2e.lens_design.space import load_space
    from optix_e2e.surrogate.ground_truth import exact_arrays
    from optix_e2e.tasks import SensorFrame, heldout_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet-wide")
    ap.add_argument("--surrogate", default="paper-triplet-e2e", help="whose terms the PSFs are computed on")
    ap.add_argument("-n", type=int, default=300)
    ap.add_argument("--boxes", type=float, nargs="*", default=[0.05, 0.1, 0.2])
    ap.add_argument("--per-box", type=int, default=40)
    ap.add_argument("--tasks", nargs="+", default=["iq-software", "low-light"])
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="runs/wide_survey")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    space, base = load_space(a.space)
    sur = load_surrogate(a.surrogate).in_space(space, base, source=a.space)
    man = sur.manifest
    limits = Limits.from_dict(space.constraints)
    nominal = np.asarray(space.values(base.data), float)
    fmax = float(base.max_field_deg)
    spot_fields = [0.0, fmax / 2, fmax]
    summary: dict = {"space": a.space, "surrogate_terms": a.surrogate, "limits": space.constraints}

    # 1. the whole space: RMS spots
    t0 = time.perf_counter()
    res = sample_designs(space, base, a.n, seed=a.seed, method="sobol", limits=limits, apertures="auto")
    nom_spot = spots_um(man, nominal[None], spot_fields)[0]
    sp = spots_um(man, res.values, spot_fields)
    with open(out / "spots.csv", "w") as f:
        f.write("design," + ",".join(f"rms_um_{x:g}deg" for x in spot_fields) + "\n")
        f.write("nominal," + ",".join(f"{x:.4f}" for x in nom_spot) + "\n")
        for i, row in enumerate(sp):
            f.write(f"{i}," + ",".join(f"{x:.4f}" for x in row) + "\n")
    summary["whole_space"] = {
        "n": int(len(sp)),
        "acceptance_rate": res.summary()["acceptance_rate"],
        "fields_deg": spot_fields,
        "nominal_rms_um": nom_spot.tolist(),
        "median_rms_um": np.median(sp, 0).tolist(),
        "p10_rms_um": np.percentile(sp, 10, 0).tolist(),
        "p90_rms_um": np.percentile(sp, 90, 0).tolist(),
        "fraction_sharper_than_nominal_every_field": float(np.all(sp < nom_spot, 1).mean()),
        "fraction_sharper_than_nominal_per_field": np.mean(sp < nom_spot, 0).tolist(),
        "seconds": time.perf_counter() - t0,
    }
    print(json.dumps({"whole_space": summary["whole_space"]}))

    # 2. boxes about the nominal: exact PSFs, task losses with the processing fixed
    from space_task_losses import FixedProcessing  # benches/: the same scoring as a dataset's

    frame = SensorFrame()
    fixed = FixedProcessing(float(base.paraxial()["f_number"]))
    half = np.array([(p.max - p.min) / 2 for p in space.params])
    lo, hi = np.array([p.min for p in space.params]), np.array([p.max for p in space.params])
    trained = {p["name"]: (p["min"], p["max"]) for p in man["trained_space"]["parameters"]}
    tlo = np.array([trained[n][0] for n in space.names])
    thi = np.array([trained[n][1] for n in space.names])

    def score(values: np.ndarray) -> tuple[list[dict], dict]:
        t = time.perf_counter()
        arrays, meta = exact_arrays(man, values)
        engine_s = time.perf_counter() - t
        rows = []
        for j, i in enumerate(tqdm(arrays["design"], desc="score", unit="design", leave=False)):
            psf = torch.as_tensor(arrays["psf_sensor"][j]).float()
            vig = torch.as_tensor(arrays["relative_illumination"][j]).float()
            heights = image_height_fractions(
                design_lens(man, values[i], float(arrays["image_distance"][j])), man["fields_deg"]
            )
            fo = FixedOptics(psf, vig, heights, full_field_px=frame.full_field_px)
            samples = heldout_set(a.size, psf.shape[-1] // 2, a.scenes, photos=[])
            row = {"design": int(i), "energy_in_window": float(arrays["energy_in_window"][j].min())}
            row.update({name: fixed.loss(fo, name, samples) for name in a.tasks})
            rows.append(row)
        return rows, {"n_refused": int(meta["n_failed"]), "engine_s": engine_s}

    nom_rows, _ = score(nominal[None])
    nom_loss = nom_rows[0]
    all_rows = [{"box": 0.0, **nom_loss, "outside_trained": False}]
    summary["boxes"] = {}
    for k, frac in enumerate(a.boxes):
        box = space.with_ranges(
            list(zip(np.maximum(lo, nominal - frac * half), np.minimum(hi, nominal + frac * half))),
            source=f"{a.space} x{frac:g}",
        )
        drawn = sample_designs(
            box, base, a.per_box, seed=a.seed + 1 + k, method="sobol", limits=limits, apertures="auto"
        )
        rows, meta = score(drawn.values)
        for r in rows:
            v = drawn.values[r["design"]]
            r.update(box=frac, outside_trained=bool(np.any((v < tlo) | (v > thi))))
        all_rows += rows
        fits = [r for r in rows if r["energy_in_window"] >= 0.9]
        summary["boxes"][f"{frac:g}"] = {
            "n": a.per_box,
            "acceptance_rate": drawn.summary()["acceptance_rate"],
            "n_refused_by_engine": meta["n_refused"],
            "engine_s_per_design": meta["engine_s"] / a.per_box,
            "n_psf_in_window": len(fits),
            "n_outside_trained_space": sum(r["outside_trained"] for r in rows),
            **{
                name: {
                    "nominal_loss": nom_loss[name],
                    "fraction_below_nominal": float(np.mean([r[name] < nom_loss[name] for r in fits]))
                    if fits
                    else None,
                    "n_below_nominal_outside_trained": sum(
                        r[name] < nom_loss[name] and r["outside_trained"] for r in fits
                    ),
                    "median_loss": float(np.median([r[name] for r in fits])) if fits else None,
                    "best_loss": float(min(r[name] for r in fits)) if fits else None,
                }
                for name in a.tasks
            },
        }
        print(json.dumps({f"box {frac:g}": summary["boxes"][f"{frac:g}"]}))
    keys = ["box", "design", "energy_in_window", "outside_trained", *a.tasks]
    with open(out / "losses.csv", "w") as f:
        f.write(",".join(keys) + "\n")
        for r in all_rows:
            f.write(",".join(str(r.get(k, "nominal" if k == "design" else "")) for k in keys) + "\n")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
