"""Relative illumination of the engine against cos^4 (a thin f/50 lens), brute-force ray
counts with our tracer and with optiland's, at the paraxial focus and 1 mm behind it; and the
time the engine takes per value. Writes a JSON report (and prints it with --json).

    python benches/relative_illumination.py --json [--rays 2097152] [--out ri.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from optix_e2e.lens import Lens
from optix_e2e.lens.illumination import relative_illumination_count

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "lens"))
from test_relative_illumination import thin_lens, vignetted_cooke  # noqa: E402  (the tests' lenses)


def ri(lens: Lens, f: float) -> float:
    return float(lens.spot(f, wavelengths_nm=[550.0])["relative_illumination"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=2**21, help="rays per brute-force point (ours)")
    ap.add_argument("--optiland-rays", type=int, default=2**19)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    rows = []
    for dz in (0.0, 1.0):
        lens = thin_lens(dz)
        for f in (10.0, 20.0, 30.0):
            rows.append(
                {
                    "lens": "thin f/50, f 50 mm",
                    "defocus_mm": dz,
                    "field_deg": f,
                    "engine": ri(lens, f),
                    "cos4": float(np.cos(np.radians(f)) ** 4),
                }
            )
        lens = vignetted_cooke(dz)
        for f in (14.0, 20.0):
            ours = relative_illumination_count(lens, f, 550.0, n_rays=a.rays)
            row = {
                "lens": "cooke-f50 with clear apertures 5.6 / 6.2 mm",
                "defocus_mm": dz,
                "field_deg": f,
                "engine": ri(lens, f),
                "count_engine_tracer": ours["relative_illumination"],
                "count_sigma": ours["sigma"],
            }
            if f == 20.0:
                try:
                    theirs = relative_illumination_count(lens, f, 550.0, n_rays=a.optiland_rays, tracer="optiland")
                    row["count_optiland"] = theirs["relative_illumination"]
                    row["count_optiland_sigma"] = theirs["sigma"]
                except ImportError:
                    row["count_optiland"] = None
            rows.append(row)
    # time per relative-illumination value (both irradiances; clear and vignetted beams)
    timing = {}
    for name, lens, f in [
        ("clear beam (cooke-f50, 20 deg)", Lens.load("cooke-f50"), 20.0),
        ("vignetted beam (cooke with apertures, 20 deg)", vignetted_cooke(0.0), 20.0),
    ]:
        t = []
        for _ in range(5):
            t0 = time.perf_counter()
            ri(lens, f)
            t.append(time.perf_counter() - t0)
        timing[name] = {"median_ms": 1e3 * float(np.median(t))}
    rep = {"rows": rows, "timing_per_value": timing}
    text = json.dumps(rep, indent=1)
    if a.out:
        a.out.write_text(text)
    print(text if a.json else "\n".join(json.dumps(r) for r in rows))


if __name__ == "__main__":
    main()
