#!/usr/bin/env python3
"""Cross-check ray aiming against optiland on the classic Cooke triplet.

    pip install optiland==0.6.3      # not a project dependency; only for this check
    python benches/compare_optiland.py [--json]

1. Monochromatic (550 nm) centroid-referenced RMS spot radius at 0, 14 and 20 deg with
paraxial aiming and with aiming at the real stop, from optiland (its CookeTriplet sample,
a uniform square pupil grid, its "iterative" aimer) and from this engine (bundled
cooke-f50, polar grid). The two lenses use different catalog fits of SK16 and the grids
differ, so compare the real/paraxial ratios first: they say whether both tools fill the
same real stop.
2. Convergence of the monochromatic RMS spot with paraxial aiming: optiland's hexapolar
grid converges as 1/rings, so its 128- and 256-ring values are extrapolated to infinite
sampling (2 x r256 - r128); ours (polar midpoint grid, 1/rings^2) at 256 rings.
This measures and prints; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np

from optix_e2e.lens import Lens

FIELDS_DEG = (0.0, 14.0, 20.0)


def optiland_rms_um(aiming: str, grid: int) -> list[float]:
    from optiland.samples.objectives import CookeTriplet

    lens = CookeTriplet()
    if aiming != "paraxial":
        lens.ray_tracer.set_aiming(aiming, max_iter=30, tol=1e-10)
    out = []
    for f in FIELDS_DEG:
        lens.trace(0.0, f / max(FIELDS_DEG), 0.55, num_rays=grid, distribution="uniform")
        s = lens.surfaces
        x, y = np.asarray(s.x[-1]), np.asarray(s.y[-1])
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        out.append(float(np.sqrt(np.mean((x - x.mean()) ** 2 + (y - y.mean()) ** 2)) * 1e3))
    return out


def optiland_extrapolated_um() -> list[float]:
    from optiland.samples.objectives import CookeTriplet

    lens = CookeTriplet()
    out = []
    for f in FIELDS_DEG:
        r = {}
        for rings in (128, 256):
            lens.trace(0.0, f / max(FIELDS_DEG), 0.55, num_rays=rings, distribution="hexapolar")
            s = lens.surfaces
            x, y = np.asarray(s.x[-1]), np.asarray(s.y[-1])
            r[rings] = float(np.sqrt(np.mean((x - x.mean()) ** 2 + (y - y.mean()) ** 2)) * 1e3)
        out.append(2 * r[256] - r[128])
    return out


def ours_rms_um(aiming: str, rings: int) -> list[float]:
    lens = Lens.load("cooke-f50")
    return [lens.spot(f, [550.0], rings=rings, aiming=aiming)["rms_um"] for f in FIELDS_DEG]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--grid", type=int, default=128, help="optiland square grid across the pupil")
    ap.add_argument("--rings", type=int, default=96, help="our polar grid rings")
    args = ap.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs = {a: optiland_rms_um(a, args.grid) for a in ("paraxial", "iterative")}
        theirs_converged = optiland_extrapolated_um()
    ours = {a: ours_rms_um(a, args.rings) for a in ("paraxial", "real")}
    result = {
        "fields_deg": list(FIELDS_DEG),
        "optiland_0_6_3": {
            "paraxial_um": theirs["paraxial"],
            "real_um": theirs["iterative"],
            "real_over_paraxial": [r / p for r, p in zip(theirs["iterative"], theirs["paraxial"])],
        },
        "optix_e2e": {
            "paraxial_um": ours["paraxial"],
            "real_um": ours["real"],
            "real_over_paraxial": [r / p for r, p in zip(ours["real"], ours["paraxial"])],
        },
        "mono_rms_converged_um": {
            "optiland_hexapolar_extrapolated": theirs_converged,
            "optix_e2e_256_rings": ours_rms_um("paraxial", 256),
        },
    }
    if args.json:
        print(json.dumps(result))
        return
    for tool in ("optiland_0_6_3", "optix_e2e"):
        r = result[tool]
        rows = ", ".join(
            f"{f:g} deg {p:.3f} -> {q:.3f} um (x{k:.3f})"
            for f, p, q, k in zip(FIELDS_DEG, r["paraxial_um"], r["real_um"], r["real_over_paraxial"])
        )
        print(f"{tool:15s} paraxial -> real aiming: {rows}")
    c = result["mono_rms_converged_um"]
    print(
        "converged mono RMS, paraxial aiming: "
        + ", ".join(
            f"{f:g} deg optiland {a:.4f} / ours {b:.4f} um"
            for f, a, b in zip(FIELDS_DEG, c["optiland_hexapolar_extrapolated"], c["optix_e2e_256_rings"])
        )
    )


if __name__ == "__main__":
    main()
