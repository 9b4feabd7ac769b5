#!/usr/bin/env python3
"""How far does a correction of the surrogate at one design hold? Zeroth order (exact minus
surrogate at the anchor: hybrid's default refinement) against first order (plus the difference
of the engine's and the surrogate's Jacobians there), along the straight path from the nominal
lens to a trained lens.

    python benches/hybrid_correction.py --point runs/tradeoff/hybrid/point.json [--json OUT.json]

``--point``: a point.json of benches/optics_tradeoff.py (its final lens; without it, a random
direction moving every parameter by up to 5 % of its range). At fractions t of the path: the
worst field's PSF relative L1 (median over channels) of the plain network, the zeroth- and the
first-order corrected models, against the engine. The surrogate's Jacobian is a central
difference at 10x the engine's chosen steps (its float32 output is noisier). It measures; it
asserts nothing.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch


def main() -> None:
    from optix_e2e.camera_design.build import load_surrogate
    from optix_e2e.camera_design.hybrid import psf_errors
    from optix_e2e.optics import DifferentiableOptics
    from optix_e2e.optics.exact import ExactOptics

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--surrogate", default="paper-triplet-e2e")
    ap.add_argument("--point", default=None)
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.01, 0.03, 0.1, 0.3, 1.0])
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    sur = load_surrogate(a.surrogate)
    eng = ExactOptics.from_surrogate(sur)
    v0 = DifferentiableOptics(sur).base_values().double().numpy()
    if a.point:
        v1 = np.array(json.load(open(a.point))["lens"], float)
    else:
        v1 = v0 + 0.05 * (eng.hi - eng.lo) * np.random.default_rng(0).uniform(-1, 1, len(v0))
    psf0, _, jp, _ = eng.jacobian(v0)

    def net(v):
        with torch.no_grad():
            return sur.psfs(torch.tensor(v, dtype=torch.float32), check=False)[0].double().numpy()

    eye = np.eye(len(v0))
    jn = np.stack([(net(v0 + eye[i] * 10 * h) - net(v0 - eye[i] * 10 * h)) / (20 * h) for i, h in enumerate(eng.steps)])
    s0 = net(v0)

    def unit(p):
        p = np.clip(p, 0.0, None)
        return p / p.sum((-2, -1), keepdims=True)

    rows = []
    for t in a.fractions:
        v = v0 + t * (v1 - v0)
        ex, _ = eng.psfs(v)
        sv = net(v)
        zeroth = sv + (psf0 - s0)
        first = zeroth + np.tensordot(v - v0, jp - jn, axes=1)
        err = {
            k: max(psf_errors(torch.tensor(p), torch.tensor(ex)))
            for k, p in (("network", sv), ("zeroth", unit(zeroth)), ("first", unit(first)))
        }
        move = float(np.abs((v - v0) / (eng.hi - eng.lo)).max())
        rows.append({"t": t, "max_move_fraction_of_range": move, **err})
        print(
            f"t {t:5.2f} (largest move {100 * move:5.2f} % of a range): worst-field error network {err['network']:.4f}, "
            f"zeroth order {err['zeroth']:.4f}, first order {err['first']:.4f}"
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"surrogate": a.surrogate, "point": a.point, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
