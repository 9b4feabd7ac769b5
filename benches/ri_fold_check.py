#!/usr/bin/env python3
"""Relative illumination where the image of the field folds (docs/accuracy.md, "Relative
illumination of folded designs"): designs of a space sampled WITHOUT the fold check, each
one's fold verdict (engine spot::field_fold) and, at three fields, the engine's relative
illumination (one ray per pupil point, by Newton from the chief ray's direction) against a
brute-force count of the flux a uniform object filling every direction to 20 deg sends to an
annulus about the chief ray's image height (lens.illumination.relative_illumination_annulus,
2^21 rays, 550 nm).

    python benches/ri_fold_check.py [--space paper-triplet-detect-wide] [-n 24] [--seed 0] [--out DIR]

Writes OUT/ri_fold_check.csv (one row per design and field) and OUT/ri_fold_check.json (the
summary); prints the summary. It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from optix_e2e.engine import EngineError
from optix_e2e.lens import Lens
from optix_e2e.lens.apertures import engine_base
from optix_e2e.lens.illumination import relative_illumination_annulus
from optix_e2e.lens_design.constraints import Limits
from optix_e2e.lens_design.sampling import sample_designs
from optix_e2e.lens_design.space import load_space

FIELDS = (5.0, 10.0, 14.9)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet-detect-wide")
    ap.add_argument("-n", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/ri_fold_check"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    space, base = load_space(a.space)
    res = sample_designs(space, base, a.n, seed=a.seed, limits=Limits.from_dict(space.constraints), field_fold=False)
    data = engine_base(base, "auto")
    rows, skipped = [], []
    t0 = time.perf_counter()
    for i, x in enumerate(res.values):
        lens = Lens(space.apply(data, x))
        fold = lens.field_fold()
        try:
            spots = [lens.spot(f, wavelengths_nm=[550.0], rings=16) for f in FIELDS]
        except EngineError as err:  # e.g. no ray reaches the image at the full field
            skipped.append({"design": i, "folds": fold is not None, "reason": str(err)})
            print(f"design {i}: {err}", flush=True)
            continue
        count = relative_illumination_annulus(
            lens, [s["chief_y_mm"] for s in spots], 550.0, theta_max_deg=20.0, n_rays=2**21
        )
        for f, s, c in zip(FIELDS, spots, count["relative_illumination"]):
            e = s["relative_illumination"]
            rows.append(
                {
                    "design": i,
                    "folds": fold is not None,
                    "fold_field_deg": None if fold is None else fold["field_deg"],
                    "field_deg": f,
                    "chief_y_mm": s["chief_y_mm"],
                    "rms_spot_um": s["rms_um"],
                    "ri_engine": e,
                    "ri_flux_count": c,
                    "ratio": e / c if c > 0 else None,
                }
            )
        print(f"design {i}: {'folds' if fold else 'one-to-one'}", flush=True)
    with open(a.out / "ri_fold_check.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)

    def spread(sel):
        r = np.array([row["ratio"] for row in rows if sel(row) and row["ratio"] is not None])
        return {
            "n": int(len(r)),
            "max_abs_rel_diff": float(np.abs(r - 1).max()) if len(r) else None,
            "median_abs_rel_diff": float(np.median(np.abs(r - 1))) if len(r) else None,
        }

    summary = {
        "space": a.space,
        "designs": a.n,
        "seed": a.seed,
        "fields_deg": list(FIELDS),
        "folding_designs": int(len({r["design"] for r in rows if r["folds"]})),
        "one_to_one": spread(lambda r: not r["folds"]),
        "one_to_one_above_1.05": spread(lambda r: not r["folds"] and r["ri_engine"] > 1.05),
        "folding": spread(lambda r: r["folds"]),
        "folding_within_5pct": int(
            sum(r["folds"] and r["ratio"] is not None and abs(r["ratio"] - 1) <= 0.05 for r in rows)
        ),
        "skipped": skipped,
        "seconds": time.perf_counter() - t0,
    }
    (a.out / "ri_fold_check.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
