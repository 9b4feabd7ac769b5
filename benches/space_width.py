#!/usr/bin/env python3
"""How good are the designs of a parameter space?  Worst-field RMS spot of refocused
designs for the bundled space and for copies of it scaled about the nominal.

    python benches/space_width.py [--space paper-triplet] [--scales 4 2 1 0.4] [-n 40]

For each scale: sample n designs (scrambled Sobol', seed 0, the space's manufacturability
limits), refocus each to its best focus over 7 fields (optix_e2e.lens_design.focus, as the dataset
generator does over its 13), and take the largest polychromatic RMS spot over the lens's
fields (engine hexapolar spot, 12 rings).  Prints one JSON line per scale: median, 90th
percentile, the fraction under 25 and 40 um, the acceptance rate.  It measures; it asserts
nothing.  docs/designs.md quotes its output for paper-triplet.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from optix_e2e import _engine
from optix_e2e.lens.apertures import engine_base
from optix_e2e.lens_design.constraints import Limits
from optix_e2e.lens_design.focus import refocus
from optix_e2e.lens_design.sampling import sample_designs
from optix_e2e.lens_design.space import Parameter, ParameterSpace, load_space


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="paper-triplet")
    ap.add_argument("--scales", type=float, nargs="+", default=[4.0, 2.0, 1.0, 0.4])
    ap.add_argument("-n", type=int, default=40)
    a = ap.parse_args()
    space, lens = load_space(a.space)
    nominal = space.values(lens.data)
    focus_fields = np.linspace(0.0, lens.max_field_deg, 7)
    for f in a.scales:
        params = [
            Parameter(p.name, p.kind, p.surface, v - f * (v - p.min), v + f * (p.max - v), p.unit)
            for p, v in zip(space.params, nominal)
        ]
        scaled = ParameterSpace(params, constraints=space.constraints)
        res = sample_designs(scaled, lens, a.n, seed=0, method="sobol", limits=Limits.from_dict(space.constraints))
        worst = []
        for x in res.values:
            d = refocus(scaled.apply(engine_base(lens, "auto"), x), "best", focus_fields, lens.wavelengths_nm)
            if not d["surfaces"][-1]["thickness"] > 0:
                worst.append(np.inf)
                continue
            js = json.dumps(d)
            try:
                worst.append(
                    max(_engine.spot(js, fd, lens.wavelengths_nm, None, 12)["rms_um"] for fd in lens.fields_deg)
                )
            except _engine.EngineError:  # no ray of a field reaches the image: a failed design
                worst.append(np.inf)
        w = np.array(worst)
        print(
            json.dumps(
                {
                    "space": a.space,
                    "scale": f,
                    "n": a.n,
                    "acceptance_rate": round(res.summary()["acceptance_rate"], 3),
                    "worst_rms_um_median": round(float(np.median(w)), 1),
                    "worst_rms_um_p90": round(float(np.percentile(w, 90)), 1),
                    "frac_under_25um": float(np.mean(w < 25)),
                    "frac_under_40um": float(np.mean(w < 40)),
                    "failed": int(np.sum(~np.isfinite(w))),
                }
            )
        )


if __name__ == "__main__":
    main()
