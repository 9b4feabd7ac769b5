"""What the engine costs at a design run's uniform random start (docs/e2e.md, "The paper-width
space"): the start drawn as `optix design --start uniform` draws it, then the engine's PSFs
(`exact_arrays`, the run's own settings) of the start and of its neighbours at the two
largest rungs of the first Jacobian's step ladder (optics/exact.py::choose_steps), with the
seconds and the PSF methods of each.

    python benches/start_engine_cost.py --config benches/results/issue34/wide.toml --seed 0
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time

from optix_e2e.camera_design.build import initial_optics_values, start_record, start_run
from optix_e2e.camera_design.config import make_config
from optix_e2e.optics.differentiable import DifferentiableOptics
from optix_e2e.surrogate.ground_truth import exact_arrays


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", required=True)
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rungs", type=float, nargs="+", default=[3e-2, 1e-2])
    a = ap.parse_args(argv)
    cfg = make_config("full", a.config, task=a.task, seed=a.seed, optics_init="uniform")
    _, _, _, sur = start_run(cfg, tempfile.mkdtemp())
    optics = DifferentiableOptics(sur)
    v = initial_optics_values(cfg, optics).double().numpy()
    lo, hi = optics.lo.double().numpy(), optics.hi.double().numpy()
    man = optics.surrogate.manifest
    rows = [("start", v)]
    for frac in a.rungs:
        for i, name in enumerate(optics.names):
            for s in (1.0, -1.0):
                w = v.copy()
                w[i] += s * frac * (hi[i] - lo[i])
                rows.append((f"{name} {s:+.0f} x {frac:g}", w))
    total, methods, slowest = 0.0, collections.Counter(), (0.0, "")
    for label, w in rows:
        t = time.perf_counter()
        _, meta = exact_arrays(man, w[None])
        dt = time.perf_counter() - t
        pm = meta.get("psf_methods", {})
        m = collections.Counter(pm["legend"][c] for codes in pm.get("codes", {}).values() for c in codes)
        methods.update(m)
        total += dt
        slowest = max(slowest, (dt, label))
        print(json.dumps({"design": label, "seconds": round(dt, 3), "methods": m, "failed": meta.get("n_failed")}))
    print(
        json.dumps(
            {
                "start": start_record(cfg),
                "designs": len(rows),
                "seconds": round(total, 2),
                "seconds_per_design": round(total / len(rows), 3),
                "slowest": {"seconds": round(slowest[0], 3), "design": slowest[1]},
                "methods": methods,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
