#!/usr/bin/env python3
"""What keeps the paper-triplet from ~10 um RMS spot across the field?  The same global
search (``optix lens optimize --global``: spot merit, field weights 1,1,3,4,5, the paper's
constraints, the sensor corner) with one limit lifted at a time, each with the same time
budget and seed:

    python benches/paper_triplet_limits.py [--lens LENS] [--minutes 5] [--out DIR] [--only V ...]

* ``baseline``: as designed (BFD >= 10 mm, the fixed N-SF11 element, PMMA);
* ``bfd5``: back focal distance >= 5 mm;
* ``free-nsf11``: the N-SF11 element's radii and thickness free (no stock lens);
* ``nlak14``: PMMA replaced by N-LAK14 (nd 1.697, vd 55.4: a high-index crown of about
  PMMA's dispersion), i.e. PMMA's index lifted;
* ``no-corner``: no minimum image height at 14.9 deg (barrel distortion may shrink the
  image of the sensor corner).

``--minutes 0`` polishes each variant locally from the nominal instead (600 iterations of
damped least squares): what lifting one limit buys at the nominal, repeatably.  For
``nlak14`` the PMMA surfaces' curvatures and aspheric terms are first scaled by
(n_PMMA - 1) / (n_N-LAK14 - 1) at 550 nm, so that each element keeps its power.

Writes DIR/limits.json and DIR/limits.csv (per variant: merit, RMS spot per field, worst
field, Petzval radius, BFD) and DIR/<variant>.json (the lens).  It measures; it asserts
nothing.  docs/designs.md quotes its output.
"""

from __future__ import annotations

import argparse
import copy
import csv
import json
import os
import time
from pathlib import Path

import numpy as np

from optix_e2e.lens import Lens
from optix_e2e.lens_design.global_search import global_search
from optix_e2e.lens_design.optimizer import Constraints, LensProblem, Merit, polish
from optix_e2e.lens_design.space import ParameterSpace

SPH = (
    "s_1_radius,s_2_radius,s_6_radius,s_7_radius,s_1_thickness,s_2_thickness,s_4_thickness,"
    "s_5_thickness,s_6_thickness,s_7_thickness"
)
ASP = "s_1_conic,s_1_4th,s_1_6th,s_1_8th,s_1_10th,s_6_conic,s_6_4th,s_6_6th,s_6_8th,s_6_10th"
HALF_DIAGONAL_MM = 6.634


def variants(raw: dict) -> dict:
    base = dict(
        efl=25.0, min_center=2.0, min_edge=2.0, min_air_gap=1.0, min_bfd=10.0, min_image_height=HALF_DIAGONAL_MM
    )
    nlak = copy.deepcopy(raw)
    n_pmma = Lens(raw).refractive_indices(550.0)[1]
    for s in nlak["surfaces"]:
        if s["material"] == "PMMA":
            s["material"] = "N-LAK14"
    n_lak = Lens(nlak).refractive_indices(550.0)[1]
    k = (n_pmma - 1.0) / (n_lak - 1.0)
    pmma = [i for i, s in enumerate(raw["surfaces"]) if s["material"] == "PMMA"]
    for i in pmma + [i + 1 for i in pmma]:  # both surfaces of each PMMA element
        s = nlak["surfaces"][i]
        if s.get("radius") not in (None, "inf"):
            s["radius"] = s["radius"] / k
        s["aspheric"] = {key: v * k for key, v in (s.get("aspheric") or {}).items()} or None
        if s["aspheric"] is None:
            del s["aspheric"]
    return {
        "baseline": (raw, SPH + "," + ASP, base),
        "bfd5": (raw, SPH + "," + ASP, {**base, "min_bfd": 5.0}),
        "free-nsf11": (raw, SPH + "," + ASP + ",s_3_radius,s_4_radius,s_3_thickness", base),
        "nlak14": (nlak, SPH + "," + ASP, base),
        "no-corner": (raw, SPH + "," + ASP, {**base, "min_image_height": None}),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lens", default="paper-triplet")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--field-weights", default="1,1,3,4,5")
    ap.add_argument("--only", nargs="*", help="variants to run (default all)")
    ap.add_argument("--out", default="runs/paper-triplet-limits")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    raw = _raw(a.lens)
    rows = []
    for name, (lens_raw, names, con) in variants(raw).items():
        if a.only and name not in a.only:
            continue
        lens = Lens(lens_raw)
        merit = Merit(
            lens, Constraints(**con), field_weights=[float(w) for w in a.field_weights.split(",")], rings=4, arms=8
        )
        space = ParameterSpace.from_names(names, lens.data, merit.footprint(lens.data, lens.to_engine_json()))
        problem = LensProblem(lens_raw, space, merit)
        if a.minutes > 0:
            g = global_search(problem, minutes=a.minutes, seed=a.seed, workers=os.cpu_count() or 1, polish_nfev=300)
            u, merit_value, feasible = np.asarray(g.best.u), g.best.merit, g.best.feasible
            polishes, basins, wall = g.polishes, len(g.basins), g.wall_s
        else:
            t0 = time.time()
            u, _, _ = polish(problem, problem.u0, max_nfev=600)
            rep = problem.report(u)
            merit_value, feasible = rep["merit"], all(c["ok"] for c in rep["constraints"])
            polishes, basins, wall = 1, 1, time.time() - t0
        designed = problem.lens_at(u)
        (out / f"{name}.json").write_text(json.dumps(designed, indent=2) + "\n")
        L = Lens(designed)
        spots = [L.spot(f, rings=128)["rms_um"] for f in L.fields_deg]
        row = {
            "variant": name,
            "merit_um": merit_value,
            "feasible": feasible,
            "worst_field_um": max(spots),
            "rms_spot_um": spots,
            "petzval_radius_mm": L.petzval()["petzval_radius_mm"],
            "bfd_mm": float(designed["surfaces"][-1]["thickness"]),
            "chief_y_corner_mm": L.spot(L.max_field_deg, rings=4)["chief_y_mm"],
            "polishes": polishes,
            "basins": basins,
            "wall_s": wall,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    (out / "limits.json").write_text(json.dumps(rows, indent=2) + "\n")
    with open(out / "limits.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "variant",
                "merit_um",
                "feasible",
                "worst_field_um",
                "rms_spot_um_per_field",
                "petzval_radius_mm",
                "bfd_mm",
                "chief_y_corner_mm",
                "polishes",
                "basins",
                "wall_s",
            ]
        )
        for r in rows:
            w.writerow(
                [
                    r["variant"],
                    f"{r['merit_um']:.4f}",
                    r["feasible"],
                    f"{r['worst_field_um']:.4f}",
                    " ".join(f"{s:.3f}" for s in r["rms_spot_um"]),
                    f"{r['petzval_radius_mm']:.3f}",
                    f"{r['bfd_mm']:.4f}",
                    f"{r['chief_y_corner_mm']:.4f}",
                    r["polishes"],
                    r["basins"],
                    f"{r['wall_s']:.1f}",
                ]
            )


def _raw(spec: str) -> dict:
    """The prescription as written (catalog glass names kept)."""
    from optix_e2e.cli.lens_optimize import _raw_lens

    return _raw_lens(spec)[0]


if __name__ == "__main__":
    main()
