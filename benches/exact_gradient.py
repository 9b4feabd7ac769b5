#!/usr/bin/env python3
"""Exact lens gradients from the engine (optics/exact.py): their accuracy, their cost, and how
the surrogate's gradients compare.

    python benches/exact_gradient.py [--surrogate paper-triplet-e2e] [--repeats 5] [--designs K] [--json OUT.json]

At the space's nominal design:
* per parameter: the chosen central-difference step, the step choice's own error estimate,
  and the error against a fourth-order reference (Richardson, (4 D(h) - D(2h)) / 3);
* the whole Jacobian: J d against a central difference along a random direction d;
* cost (median of --repeats): one exact Jacobian (2P + 1 designs in one engine call), the
  step choice (once per run), one surrogate forward + backward of the same PSFs;
* the engine's one-pass gradient (``exact_gradient = "one-pass"``, optics/exact.py): its time
  against the forward PSF set and the Jacobian, and J^T g against the Jacobian's for three
  random g (relative vector norm), at the nominal and at ``--designs`` designs drawn uniformly
  over the space's ranges (seeded; a design the engine rejects is counted and skipped; a
  design without a one-pass gradient is listed with the engine's reason);
* agreement with the surrogate's lens gradient on two losses: a task-like one (L1 of a textured
  96 x 96 image through the lens against the sharp image) and the PSFs' mean second moment
  (spot size, weighting the tails): sign on the parameters with >= 5 % of the largest
  component, and the cosine.
It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch


def main() -> None:
    from optix_e2e.camera_design.build import load_surrogate
    from optix_e2e.optics import DifferentiableOptics
    from optix_e2e.optics.exact import EngineRejectedDesign, ExactOptics, choose_steps

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--surrogate", default="paper-triplet-e2e")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--designs", type=int, default=0, help="random designs for the one-pass gradient's check")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    sur = load_surrogate(a.surrogate)
    v = DifferentiableOptics(sur).base_values().double().numpy()
    eng = ExactOptics.from_surrogate(sur)
    t0 = time.perf_counter()
    eng.step_choice = choose_steps(eng, v)
    step_choice_s = time.perf_counter() - t0
    eng.steps = eng.step_choice.steps
    times = []
    for _ in range(a.repeats):
        eng._cache = None
        t0 = time.perf_counter()
        psf, vig, jp, jv = eng.jacobian(v)
        times.append(time.perf_counter() - t0)
    p = len(v)
    h = eng.steps
    psf2, vig2, _ = eng._run(np.concatenate([v[None] + s * np.diag(2 * h) for s in (1.0, -1.0)]))
    rows = []
    for i, name in enumerate(eng.names):
        d2 = np.concatenate(
            [((psf2[i] - psf2[p + i]) / (4 * h[i])).ravel(), ((vig2[i] - vig2[p + i]) / (4 * h[i])).ravel()]
        )
        d1 = np.concatenate([jp[i].ravel(), jv[i].ravel()])
        ref = (4 * d1 - d2) / 3
        rows.append(
            {
                "parameter": name,
                "step": float(h[i]),
                "step_fraction_of_range": float(h[i] / (eng.hi[i] - eng.lo[i])),
                "estimated_rel_error": float(eng.step_choice.rel_error[i]),
                "rel_error_vs_fourth_order": float(np.abs(d1 - ref).sum() / max(np.abs(ref).sum(), 1e-300)),
            }
        )
    # the whole Jacobian at once: J d against a central difference along a random direction d
    # (every parameter moving by up to 0.1 % of its range)
    d = np.random.default_rng(7).uniform(-1, 1, p) * 1e-3 * (eng.hi - eng.lo)
    pd, vd, _ = eng._run(np.stack([v + d, v - d]))
    fd = np.concatenate([((pd[0] - pd[1]) / 2).ravel(), ((vd[0] - vd[1]) / 2).ravel()])
    lin = np.concatenate([np.tensordot(d, jp, axes=1).ravel(), np.tensordot(d, jv, axes=1).ravel()])
    direction_error = float(np.abs(fd - lin).sum() / np.abs(fd).sum())
    # the surrogate's forward + backward of the same PSFs
    st = []
    for _ in range(a.repeats):
        x = torch.tensor(v, dtype=torch.float32, requires_grad=True)
        t0 = time.perf_counter()
        ps, vs = sur.psfs(x, check=False)
        (ps.sum() * 0 + (ps**2).sum() + vs.sum()).backward()
        st.append(time.perf_counter() - t0)

    # the one-pass gradient: time (forward set, VJP) and J^T g against the Jacobian's
    rng = np.random.default_rng(11)

    def one_pass_check(x, jp, jv, label):
        errs, why = [], None
        for _ in range(3):
            g_psf, g_vig = rng.uniform(-1, 1, jp.shape[1:]), rng.uniform(-1, 1, jv.shape[1:])
            want = (jp * g_psf).reshape(len(x), -1).sum(1) + (jv * g_vig).reshape(len(x), -1).sum(1)
            got, why = eng._one_pass(x, g_psf, g_vig)
            if got is None:
                break
            errs.append(float(np.linalg.norm(got - want) / np.linalg.norm(want)))
        return {"design": label, "rel_error": errs, "fallback": why}

    checks = [one_pass_check(v, jp, jv, "nominal")]
    fwd, vjp = [], []
    g_psf, g_vig = rng.uniform(-1, 1, psf.shape), rng.uniform(-1, 1, vig.shape)
    for _ in range(a.repeats):
        eng._cache = None
        t0 = time.perf_counter()
        eng.psfs(v)
        fwd.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        eng._one_pass(v, g_psf, g_vig)
        vjp.append(time.perf_counter() - t0)
    rejected = 0
    draw = np.random.default_rng(5)
    for k in range(a.designs):
        x = eng.lo + (eng.hi - eng.lo) * draw.uniform(0.05, 0.95, p)
        try:
            _, _, jpx, jvx = eng.jacobian(x)
        except EngineRejectedDesign:
            rejected += 1
            continue
        checks.append(one_pass_check(x, jpx, jvx, f"draw {k}"))

    def spot2(psf):
        s = psf.shape[-1]
        c = torch.arange(s, dtype=psf.dtype) - s // 2
        yy, xx = torch.meshgrid(c, c, indexing="ij")
        m = psf.sum((-2, -1))
        cy, cx = (psf * yy).sum((-2, -1)) / m, (psf * xx).sum((-2, -1)) / m
        return ((psf * ((yy - cy[..., None, None]) ** 2 + (xx - cx[..., None, None]) ** 2)).sum((-2, -1)) / m).mean()

    img = torch.nn.functional.avg_pool2d(torch.rand(1, 3, 96, 96, generator=torch.Generator().manual_seed(0)), 3, 1, 1)
    agreement = {}
    for loss_name in ("render_l1", "psf_second_moment"):
        grads = {}
        for backend in ("exact", "surrogate"):
            o = DifferentiableOptics(sur, backend=backend)
            o._exact = eng
            if loss_name == "render_l1":
                loss = (o(img) - img).abs().mean()
            else:
                pp, vv = o.psfs()
                loss = spot2(pp.double()) + vv.double().mean()
            loss.backward()
            grads[backend] = o.u.grad.double().numpy()
        e, s = grads["exact"], grads["surrogate"]
        dom = np.abs(e) >= 0.05 * np.abs(e).max()
        agreement[loss_name] = {
            "cosine": float(e @ s / np.linalg.norm(e) / np.linalg.norm(s)),
            "dominant": int(dom.sum()),
            "sign_agree_dominant": int((np.sign(e[dom]) == np.sign(s[dom])).sum()),
            "disagree": [n for n, d, x, y in zip(sur.param_names, dom, e, s) if d and np.sign(x) != np.sign(y)],
            "exact": [float(x) for x in e],
            "surrogate": [float(x) for x in s],
        }
    out = {
        "surrogate": a.surrogate,
        "parameters": p,
        "torch_threads": torch.get_num_threads(),
        "exact_jacobian_s": float(np.median(times)),
        "exact_jacobian_designs": 2 * p + 1,
        "step_choice_s": step_choice_s,
        "step_choice_designs": 2 * p * len(eng.step_choice.ladder),
        "surrogate_forward_backward_s": float(np.median(st)),
        "random_direction_rel_error": direction_error,
        "one_pass": {
            "forward_set_s": float(np.median(fwd)),
            "vjp_s": float(np.median(vjp)),
            "vjp_over_forward": float(np.median(vjp) / np.median(fwd)),
            "jacobian_over_vjp": float(np.median(times) / np.median(vjp)),
            "checks": checks,
            "designs_drawn": a.designs,
            "designs_rejected": rejected,
        },
        "per_parameter": rows,
        "agreement": agreement,
    }
    print(f"{'parameter':12s} {'step/range':>10s} {'est.err':>8s} {'vs 4th':>8s}")
    for r in rows:
        print(
            f"{r['parameter']:12s} {r['step_fraction_of_range']:10.0e} {r['estimated_rel_error']:8.2e} "
            f"{r['rel_error_vs_fourth_order']:8.2e}"
        )
    print(
        f"exact Jacobian ({2 * p + 1} designs): {out['exact_jacobian_s'] * 1e3:.0f} ms; step choice (once, "
        f"{out['step_choice_designs']} designs): {step_choice_s:.1f} s; surrogate forward+backward: "
        f"{out['surrogate_forward_backward_s'] * 1e3:.0f} ms ({torch.get_num_threads()} threads)"
    )
    print(f"J d against the central difference along a random direction: {direction_error:.2e} relative L1")
    op = out["one_pass"]
    print(
        f"one-pass gradient: {op['vjp_s'] * 1e3:.0f} ms ({op['vjp_over_forward']:.1f}x the forward set's "
        f"{op['forward_set_s'] * 1e3:.0f} ms, the Jacobian {op['jacobian_over_vjp']:.1f}x it)"
    )
    for c in checks:
        errs = ", ".join(f"{e:.1e}" for e in c["rel_error"])
        print(
            f"  {c['design']}: J^T g relative error {errs}"
            + (f"; no one-pass gradient: {c['fallback']}" if c["fallback"] else "")
        )
    if rejected:
        print(f"  ({rejected} of {a.designs} drawn designs rejected by the engine)")
    for k, g in agreement.items():
        print(
            f"{k}: cosine {g['cosine']:.4f}, sign agrees on {g['sign_agree_dominant']} of {g['dominant']} dominant "
            f"parameters" + (f" (not: {', '.join(g['disagree'])})" if g["disagree"] else "")
        )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
