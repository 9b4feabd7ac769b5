#!/usr/bin/env python3
"""A parameter space around our nominal with the relative widths of the paper's Table 1:

    python scripts/paper_width_space.py [--space paper-triplet-e2e] [--out OUT.toml]

The paper's triplet is not ours (its radii are about 12 mm, ours 8-92 mm), so its ranges are
carried over as widths relative to each parameter, not as values:

* radii: the same parameter's Table 1 half-width over its mid-range value (13-22 %),
* conics: Table 1's half-width as it is (+-0.39 on surface 1, +-0.49 on surface 6),
* air gaps: Table 1's relative half-width of the same gap (l_12 38 %, l_2STO 80 %, l_STO3
  100 %) of max(gap, 1 mm), floored at 0 (our lens-2-to-stop gap is 0.19 mm),
* aspheric terms (Table 1's ranges for them are 0.7-30 x the mid-range value, many spanning
  zero): +- the coefficient that puts ``--sag-um`` of sag at the surface's clear
  semi-diameter, or +- 72 % of the value (Table 1's s_1_4th) where that is wider.

The space keeps the parameters, kinds, surfaces and limits of SPACE. It prints each range.
"""

from __future__ import annotations

import argparse

from optix_e2e.lens_design.space import ASPHERE_KINDS, Parameter, load_space

# Table 1 of the paper: (min, max) of the parameters whose width we carry over
TABLE1 = {
    "s_1_radius": (9.85, 14.98),
    "s_1_conic": (-0.49, 0.29),
    "s_2_radius": (9.45, 14.82),
    "l_12": (4.58, 10.11),
    "l_2STO": (1.03, 9.22),
    "l_STO3": (0.0, 9.86),
    "s_6_radius": (13.38, 18.17),
    "s_6_conic": (-0.49, 0.49),
    "s_7_radius": (-15.05, -11.50),
}
ASPHERE_REL = 0.72  # Table 1's s_1_4th: -9.06e-5 .. -1.45e-5, i.e. +-72 % of its mid-range value


def half_width(p: Parameter, v: float, lens: dict, sag_um: float) -> float:
    if p.name in TABLE1:
        lo, hi = TABLE1[p.name]
        half, mid = (hi - lo) / 2, (hi + lo) / 2
        if p.kind == "conic":
            return half
        rel = half / abs(mid)
        return rel * (max(abs(v), 1.0) if p.kind == "air_gap" else abs(v))
    order = ASPHERE_KINDS.get(p.kind, 0)
    if order:
        h = float(lens["surfaces"][p.surface - 1]["semi_diameter"])
        return max(ASPHERE_REL * abs(v), 1e-3 * sag_um / h**order)
    raise SystemExit(f"{p.name}: no rule for a {p.kind} parameter")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet-e2e")
    ap.add_argument("--out", default="python/optix_e2e/bundled/spaces/paper-triplet-wide.toml")
    ap.add_argument("--sag-um", type=float, default=50.0, help="aspheric terms: sag at the clear semi-diameter")
    a = ap.parse_args()
    space, lens = load_space(a.space)
    values = space.values(lens.data)
    ranges = []
    for p, v in zip(space.params, values):
        w = half_width(p, v, lens.data, a.sag_um)
        ranges.append((max(v - w, 0.0) if p.kind == "air_gap" else v - w, v + w))
    out = space.with_ranges(
        ranges,
        source=a.out,
        description=(
            f"The paper's Table 1 widths around our nominal ({lens.name}): radii +-13-22 %, conics +-0.39/0.49, "
            f"air gaps +-38-100 % of max(gap, 1 mm), aspheric terms +- max(72 %, {a.sag_um:g} um of sag at the "
            "clear semi-diameter); made by scripts/paper_width_space.py (docs/e2e.md)"
        ),
    )
    out.save_toml(a.out)
    for p, v in zip(out.params, values):
        print(f"{p.name:>12}  {p.min:+.6g} .. {p.max:+.6g}  (nominal {v:+.6g})")


if __name__ == "__main__":
    main()
