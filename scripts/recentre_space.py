#!/usr/bin/env python3
"""Re-centre a parameter space on a new nominal design, keeping each range's shape:

    python scripts/recentre_space.py SPACE NEW_LENS OUT.toml [--lens-ref NAME]

Radii and air gaps keep their offsets relative to the nominal (scaled by new / old), the
other kinds (conics, aspheric terms) their offsets in absolute terms.  Notes, description
and constraints are kept.  Used for bundled/spaces/paper-triplet.toml (docs/designs.md).
"""

from __future__ import annotations

import argparse

from optix_e2e.lens import Lens
from optix_e2e.space import Parameter, ParameterSpace, load_space

RELATIVE = ("radius", "air_gap", "thickness")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("space")
    ap.add_argument("new_lens")
    ap.add_argument("out")
    ap.add_argument("--lens-ref", help="base-lens name to write (default: the space's)")
    a = ap.parse_args()
    space, old = load_space(a.space)
    new = Lens.load(a.new_lens)
    v0, v1 = space.values(old.data), space.values(new.data)
    params = []
    for p, a0, a1 in zip(space.params, v0, v1):
        s = a1 / a0 if p.kind in RELATIVE and a0 != 0 else 1.0
        lo, hi = a1 + (p.min - a0) * s, a1 + (p.max - a0) * s
        params.append(Parameter(p.name, p.kind, p.surface, min(lo, hi), max(lo, hi), p.unit))
    out = ParameterSpace(params, source=a.out, lens_ref=a.lens_ref or space.lens_ref,
                         description=space.description, notes=space.notes, constraints=space.constraints)
    out.save_toml(a.out)
    for p, x in zip(params, v1):
        print(f"{p.name:>12}  {p.min:+.6g} .. {p.max:+.6g}  (nominal {x:+.6g})")


if __name__ == "__main__":
    main()
