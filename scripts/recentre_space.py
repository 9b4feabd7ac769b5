#!/usr/bin/env python3
"""Re-centre a parameter space on a new nominal design with the bundled paper-triplet
space's rules (docs/designs.md):

    python scripts/recentre_space.py SPACE NEW_LENS OUT.toml [--lens-ref NAME] [--scale S]

radii +-3.75 %, conics +-0.1, air gaps 0.875x .. 1.125x + 0.25 mm, aspheric terms a4 and
up +- a quarter of max(50 %, the coefficient giving 10 um of sag at the new lens's clear
semi-diameter); any other parameter (the r^2 terms) keeps its width, moved with the
nominal (as do glass thicknesses, if the space has any).  ``--scale`` multiplies every half-width (default 1).  Notes, description and
constraints are kept.
"""

from __future__ import annotations

import argparse

from optix_e2e.lens import Lens
from optix_e2e.lens_design.space import ASPHERE_KINDS, load_space


def rule(p, v: float, lens: dict) -> tuple[float, float] | None:
    if p.kind == "radius":
        return v * (1 - 0.0375), v * (1 + 0.0375)
    if p.kind == "conic":
        return v - 0.1, v + 0.1
    if p.kind == "air_gap":
        return 0.875 * v, 1.125 * v + 0.25
    order = ASPHERE_KINDS.get(p.kind, 0)
    if order >= 4:
        h = lens["surfaces"][p.surface - 1].get("semi_diameter")
        if not h:
            raise SystemExit(
                f"{p.name}: surface {p.surface} of the new lens has no clear semi-diameter "
                f"(write them with optix lens optimize --set-semi-diameters)"
            )
        h = float(h)
        w = 0.25 * max(0.5 * abs(v), 0.01 / h**order)
        return v - w, v + w
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("space")
    ap.add_argument("new_lens")
    ap.add_argument("out")
    ap.add_argument("--lens-ref", help="base-lens name to write (default: the space's)")
    ap.add_argument("--scale", type=float, default=1.0, help="multiply every half-width by this")
    a = ap.parse_args()
    space, old = load_space(a.space)
    new = Lens.load(a.new_lens)
    v0, v1 = space.values(old.data), space.values(new.data)
    ranges = []
    for p, a0, a1 in zip(space.params, v0, v1):
        lo, hi = rule(p, a1, new.data) or (a1 + p.min - a0, a1 + p.max - a0)
        ranges.append((a1 - a.scale * (a1 - lo), a1 + a.scale * (hi - a1)))
    out = space.with_ranges(ranges, source=a.out, lens_ref=a.lens_ref)
    out.save_toml(a.out)
    for p, x in zip(out.params, v1):
        print(f"{p.name:>12}  {p.min:+.6g} .. {p.max:+.6g}  (nominal {x:+.6g})")


if __name__ == "__main__":
    main()
