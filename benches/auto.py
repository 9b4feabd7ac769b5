#!/usr/bin/env python3
"""Wall-clock cost of ``method="auto"`` against the cheapest candidate that meets the target
in hindsight, on held-out random designs of the bundled spaces (docs/accuracy.md).

    python benches/auto.py [--target 0.02] [--designs 3] [--seed 2026] [--repeats 3] [--json]

Every candidate is run and timed (median of ``--repeats`` runs when it is fast), and so is
the auto call including its probe. Prints the summary of optix_e2e.accuracy.auto_check:
met fraction, time ratios (of the means, per-case median and worst) and the same ratios in
the engine's modelled costs. It measures; it asserts nothing (tests/accuracy/test_auto.py asserts the
met fraction and the modelled ratio, which do not depend on how busy the machine is).
"""

from __future__ import annotations

import argparse
import json

from optix_e2e.accuracy.auto_check import check_case, held_out_cases, summarize

SPACES = ["cooke-f50", "paper-triplet", "double-gauss-f5"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", type=float, default=0.02)
    ap.add_argument("--designs", type=int, default=3, help="designs per space")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    rows = [check_case(c, target=a.target, repeats=a.repeats) for c in held_out_cases(SPACES, a.designs, a.seed)]
    s = summarize(rows)
    if a.json:
        print(json.dumps(s))
        return
    print(
        f"{s['n_cases']} cases, auto met {a.target:.1%} in {s['met_fraction']:.0%}; time auto / hindsight: "
        f"{s['cost_ratio_of_means']:.2f} (means), per case median {s['cost_ratio_median']:.2f}, "
        f"max {s['cost_ratio_max']:.2f}; modelled cost ratio {s['modelled_cost_ratio_of_means']:.2f}; "
        f"choices {s['choices']}"
    )


if __name__ == "__main__":
    main()
