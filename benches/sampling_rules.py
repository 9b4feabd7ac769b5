#!/usr/bin/env python3
"""How many designs of a space pass its manufacturability limits under the one definition
(each design at its own clear apertures, optix_e2e.lens_design.constraints) and under the
rule of the datasets made before it (the base lens's clear apertures for every design).

    python benches/sampling_rules.py [--spaces paper-triplet-e2e paper-triplet-detect] [-n 200]

For each space: n accepted designs from uniform draws (seed 1) under each rule; prints one
JSON line per space with the draws, acceptance rates and rejections by reason, and the time
the one definition takes per candidate. It measures; it asserts nothing. docs/e2e.md quotes
its output.
"""

from __future__ import annotations

import argparse
import json
import time

from optix_e2e.lens_design.constraints import Limits
from optix_e2e.lens_design.sampling import sample_designs
from optix_e2e.lens_design.space import load_space


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spaces", nargs="+", default=["paper-triplet-e2e", "paper-triplet-detect"])
    ap.add_argument("-n", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    for name in args.spaces:
        space, base = load_space(name)
        limits = Limits.from_dict(space.constraints)
        row = {"space": name, "n": args.n, "seed": args.seed}
        for rule in ("auto", "base-lens"):
            t0 = time.perf_counter()
            res = sample_designs(space, base, args.n, seed=args.seed, method="uniform", limits=limits, apertures=rule)
            wall = time.perf_counter() - t0
            row[rule] = {
                "drawn": res.drawn,
                "acceptance_rate": round(args.n / res.drawn, 4),
                "rejected_by_reason": {k: v for k, v in res.rejected.items() if v},
                "ms_per_candidate": round(1e3 * wall / res.drawn, 2),
            }
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
