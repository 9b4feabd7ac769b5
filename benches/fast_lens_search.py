#!/usr/bin/env python3
"""Can a fast lens be made in the detection space, and what does it cost in RMS spot?
(issue 35 item 1)

    python benches/fast_lens_search.py [--space paper-triplet-detect-wide] [--f-numbers 3.2 3.6 4.0]
                                       [--minutes 12] [--workers 1] [--out DIR]

For each f-number, the same global search (``optix lens optimize --global``: spot merit, field
weights 1,1,1,2,5 as the nominal's search, EFL 25 mm, the sensor corner at >= 6.634 mm, the
space's limits) over every parameter of SPACE but the aperture, which is held at that
f-number, plus the back focus (s_7_thickness, default bounds: the dataset refocuses every
design, the search must too). The start is the nominal (paper-triplet) opened to that
f-number with no clear apertures (each design's own footprint sizes its surfaces); where its
lens-2-to-stop gap is too thin for the wider beam (the stop plane would cross lens 2's rear
surface), the gap starts at the middle of its range.

The found lens is then checked as the sampler, the guard and the final checks check it (the
one constraint definition: lens_design/constraints.py, at its own clear apertures) and
against the space's ranges; its polychromatic RMS spot per field is traced with 128 rings.

Writes DIR/search.json and DIR/search.csv (per f-number: feasible, limits' problems, RMS spot
per field, the parameters on a range end, the search's polishes and wall time) and
DIR/f<N>.json (each lens). It measures; it asserts nothing. docs/detection.md quotes it.
"""

from __future__ import annotations

import argparse
import copy
import csv
import json
import time
from pathlib import Path

import numpy as np

from optix_e2e.lens import Lens
from optix_e2e.lens_design.constraints import Limits, check_design, own_apertures
from optix_e2e.lens_design.global_search import global_search
from optix_e2e.lens_design.optimizer import Constraints, LensProblem, Merit
from optix_e2e.lens_design.space import ParameterSpace, load_space, parameter_from_name

HALF_DIAGONAL_MM = 6.634


def start_lens(base: dict, f_number: float, space: ParameterSpace) -> dict:
    """The nominal at ``f_number`` without clear apertures; a lens-2-to-stop gap too thin for
    the wider beam opened to the middle of its range."""
    raw = copy.deepcopy(base)
    raw["aperture"] = {"type": "fno", "value": float(f_number)}
    for s in raw["surfaces"]:
        s.pop("semi_diameter", None)
    try:
        Lens(raw)
    except Exception:  # the stop plane crosses lens 2's rear surface at the wider beam
        gap = next(p for p in space.params if p.name == "l_2STO")
        gap.set(raw, 0.5 * (gap.min + gap.max))
    return raw


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet-detect-wide")
    ap.add_argument("--f-numbers", type=float, nargs="+", default=[3.2, 3.6, 4.0])
    ap.add_argument("--minutes", type=float, default=12.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--field-weights", default="1,1,1,2,5")
    ap.add_argument("--out", default="runs/fast_lens_search")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    space_all, base = load_space(a.space)
    limits = Limits.from_dict(space_all.constraints, a.space)
    rows = []
    for fno in a.f_numbers:
        raw = start_lens(base.data, fno, space_all)
        lens = Lens(raw)
        con = Constraints(
            efl=25.0,
            min_center=limits.min_center,
            min_edge=limits.min_edge,
            min_air_gap=limits.min_air_gap,
            min_bfd=limits.min_bfd,
            min_image_height=HALF_DIAGONAL_MM,
        )
        merit = Merit(lens, con, field_weights=[float(w) for w in a.field_weights.split(",")], rings=4, arms=8)
        params = [p for p in space_all.params if p.kind != "f_number"]
        params.append(
            parameter_from_name("s_7_thickness", raw, semi_diameters=merit.footprint(raw, lens.to_engine_json()))
        )
        space = ParameterSpace(params, source=f"{a.space} at f/{fno:g}")
        problem = LensProblem(raw, space, merit)
        t0 = time.time()
        g = global_search(problem, minutes=a.minutes, seed=a.seed, workers=a.workers, polish_nfev=300)
        designed = problem.lens_at(np.asarray(g.best.u))
        (out / f"f{fno:g}.json").write_text(json.dumps(designed, indent=2) + "\n")
        L = Lens(designed)
        resolved = L.data
        problems = check_design(resolved, own_apertures(resolved), limits)
        outside = space_all.check_bounds(resolved)
        values = dict(zip(space_all.names, space_all.values(resolved)))
        on_end = [
            p.name
            for p in space_all.params
            if p.kind != "f_number" and min(values[p.name] - p.min, p.max - values[p.name]) <= 1e-6 * (p.max - p.min)
        ]
        spots = [L.spot(f, rings=128)["rms_um"] for f in L.fields_deg]
        row = {
            "f_number": fno,
            "feasible": not problems and not outside,
            "problems": problems + outside,
            "rms_spot_um": spots,
            "worst_field_um": max(spots),
            "fields_deg": list(L.fields_deg),
            "on_range_end": on_end,
            "center_thickness_mm": {"lens1": values["s_1_thickness"], "lens3": values["s_6_thickness"]}
            if "s_1_thickness" in values and "s_6_thickness" in values
            else None,
            "merit_um": g.best.merit,
            "polishes": g.polishes,
            "basins": len(g.basins),
            "wall_s": time.time() - t0,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    nominal = Lens(base.data)
    ref = {"f_number": float(base.data["aperture"]["value"])}
    ref["rms_spot_um"] = [nominal.spot(f, rings=128)["rms_um"] for f in nominal.fields_deg]
    (out / "search.json").write_text(json.dumps({"space": a.space, "nominal": ref, "rows": rows}, indent=2) + "\n")
    with open(out / "search.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["f_number", "feasible", "problems", "rms_spot_um_per_field", "worst_field_um", "on_range_end"])
        w.writerow(["nominal", "", "", " ".join(f"{s:.3f}" for s in ref["rms_spot_um"]), "", ""])
        for r in rows:
            w.writerow(
                [
                    r["f_number"],
                    r["feasible"],
                    "; ".join(r["problems"]),
                    " ".join(f"{s:.3f}" for s in r["rms_spot_um"]),
                    f"{r['worst_field_um']:.3f}",
                    " ".join(r["on_range_end"]),
                ]
            )


if __name__ == "__main__":
    main()
