"""Exact optics in the loop (optics/exact.py): central-difference gradients of the engine's
PSFs and vignetting against a higher-order reference, against the surrogate's gradients, as
an autograd Function, and the engine's rejections as named errors (never NaN)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optix_e2e.camera_design.build import load_surrogate
from optix_e2e.optics import DifferentiableOptics
from optix_e2e.optics.exact import EngineRejectedDesign, ExactOptics, exact_psfs


@pytest.fixture(scope="module")
def sur():
    return load_surrogate("paper-triplet-e2e")


@pytest.fixture(scope="module")
def nominal_jacobian(sur):
    eng = ExactOptics.from_surrogate(sur)
    v = DifferentiableOptics(sur).base_values().double().numpy()
    psf, vig, jp, jv = eng.jacobian(v)
    return eng, v, psf, vig, jp, jv


def test_exact_jacobian_matches_a_fourth_order_reference_on_every_parameter(nominal_jacobian):
    """Each parameter's column (PSFs and vignetting of all 13 fields x RGB) against the
    five-point stencil (Richardson: (4 D(h) - D(2h)) / 3, truncation O(h^4)) at the chosen step.
    The difference is (D(h) - D(2h)) / 3, Richardson's estimate of D(h)'s own error: a
    consistency check; the random-direction test below is the independent one.
    Measured on the paper-triplet e2e nominal (benches/exact_gradient.py): relative L1 error
    1e-5 to 8e-5, 2.4e-4 for s_6_conic (whose derivative is tiny); asserted below 1 % on every
    one of the 19 parameters."""
    eng, v, psf, vig, jp, jv = nominal_jacobian
    h = eng.steps
    p = len(v)
    rows = [v[None] + s * np.diag(2 * h) for s in (1.0, -1.0)]
    psf2, vig2, _ = eng._run(np.concatenate(rows))
    assert all(x is not None for x in psf2)
    errs = []
    for i in range(p):
        d2 = np.concatenate(
            [((psf2[i] - psf2[p + i]) / (4 * h[i])).ravel(), ((vig2[i] - vig2[p + i]) / (4 * h[i])).ravel()]
        )
        d1 = np.concatenate([jp[i].ravel(), jv[i].ravel()])
        ref = (4 * d1 - d2) / 3
        errs.append(np.abs(d1 - ref).sum() / np.abs(ref).sum())
    assert np.isfinite(jp).all() and np.isfinite(jv).all()
    assert max(errs) < 0.01, dict(zip(eng.names, np.round(errs, 5)))
    # the step choice's own error estimate is of the same order, and was computed for every parameter
    assert eng.step_choice is not None and np.all(eng.step_choice.rel_error < 0.03)


def test_exact_jacobian_predicts_a_move_along_a_random_direction(nominal_jacobian):
    """An independent check of the whole Jacobian (every column, signs and scales together): the
    change of the PSFs and vignetting along a random direction d (every parameter moving by up
    to 0.1 % of its range), by a central difference along d, against J d. Measured 0.04 %;
    asserted below 2 %."""
    eng, v, psf, vig, jp, jv = nominal_jacobian
    rng = np.random.default_rng(7)
    d = rng.uniform(-1, 1, len(v)) * 1e-3 * (eng.hi - eng.lo)
    out, outv, _ = eng._run(np.stack([v + d, v - d]))
    fd = np.concatenate([((out[0] - out[1]) / 2).ravel(), ((outv[0] - outv[1]) / 2).ravel()])
    lin = np.concatenate([np.tensordot(d, jp, axes=1).ravel(), np.tensordot(d, jv, axes=1).ravel()])
    err = np.abs(fd - lin).sum() / np.abs(fd).sum()
    assert err < 0.02, err


def test_chosen_steps_balance_truncation_and_round_off(nominal_jacobian):
    """The estimate |D(h_j) - D(h_j+1)| falls with h (truncation) and rises again (round-off):
    for most parameters the chosen rung is inside the ladder, not at its ends."""
    eng = nominal_jacobian[0]
    j = np.argmin(eng.step_choice.curves, axis=1)
    inner = (j > 0) & (j < eng.step_choice.curves.shape[1] - 1)
    assert inner.sum() >= 0.7 * len(j), list(zip(eng.names, j))


def test_autograd_function_returns_the_jacobian_contraction(nominal_jacobian, sur):
    eng, v, psf, vig, jp, jv = nominal_jacobian
    g = torch.Generator().manual_seed(0)
    w_psf = torch.rand(psf.shape, generator=g, dtype=torch.float64)
    w_vig = torch.rand(vig.shape, generator=g, dtype=torch.float64)
    x = torch.tensor(v, requires_grad=True)
    eng.gradient = "differences"
    try:
        p, q = exact_psfs(x, eng)
        ((p * w_psf).sum() + (q * w_vig).sum()).backward()
    finally:
        eng.gradient = "one-pass"
    want = (jp * w_psf.numpy()).reshape(len(v), -1).sum(1) + (jv * w_vig.numpy()).reshape(len(v), -1).sum(1)
    np.testing.assert_allclose(x.grad.numpy(), want, rtol=1e-10, atol=1e-14)
    # without gradients only the design itself is computed
    n = eng.designs_computed
    with torch.no_grad():
        exact_psfs(torch.tensor(v + 1e-3 * (eng.hi - eng.lo)), eng)
    assert eng.designs_computed == n + 1


def test_the_one_pass_gradient_is_the_jacobians_contraction(nominal_jacobian):
    """The engine's one-pass gradient (the default, ``exact_gradient = "one-pass"``) against the
    central-difference Jacobian's J^T g for random g over all 13 fields x RGB PSFs and the
    vignetting, every parameter of the space: refocus, auto's method, the sensor binning and the
    normalization included. Measured 6e-5 and 5e-4 relative (vector norm); asserted <= 0.5 %.
    The backward pass is one engine call: no designs computed, no fallback."""
    eng, v, psf, vig, jp, jv = nominal_jacobian
    rng = np.random.default_rng(3)
    for _ in range(2):
        g_psf, g_vig = rng.uniform(-1, 1, psf.shape), rng.uniform(-1, 1, vig.shape)
        x = torch.tensor(v, requires_grad=True)
        p, q = exact_psfs(x, eng)
        n, one = eng.designs_computed, eng.one_pass
        ((p * torch.as_tensor(g_psf)).sum() + (q * torch.as_tensor(g_vig)).sum()).backward()
        assert eng.designs_computed == n and eng.one_pass == one + 1 and eng.last["fallback"] is None
        want = (jp * g_psf).reshape(len(v), -1).sum(1) + (jv * g_vig).reshape(len(v), -1).sum(1)
        err = np.linalg.norm(x.grad.numpy() - want) / np.linalg.norm(want)
        assert err <= 5e-3, err


@pytest.mark.slow
def test_the_one_pass_gradient_at_a_drawn_detection_design_with_the_f_number():
    """Away from a nominal, in the detection space (the f-number a parameter, 20 in all): a
    design drawn over the middle half of its ranges (seeded), J^T g against the Jacobian by differences (steps of
    3e-4 of each range). Measured 4e-5 to 2.5e-4 (benches/exact_gradient.py); asserted
    <= 0.5 %."""
    det = load_surrogate("paper-triplet-detect")
    eng = ExactOptics.from_surrogate(det)
    eng.steps = 3e-4 * (eng.hi - eng.lo)  # the step choice's usual rung (its ladder is 280 designs)
    rng = np.random.default_rng(5)
    for _ in range(5):  # the first draw the engine takes
        x = eng.lo + (eng.hi - eng.lo) * rng.uniform(0.25, 0.75, len(eng.lo))
        try:
            psf, vig, jp, jv = eng.jacobian(x)
            break
        except EngineRejectedDesign:
            continue
    else:
        pytest.fail("no drawn design the engine takes")
    assert "f_number" in eng.names
    g_psf, g_vig = rng.uniform(-1, 1, psf.shape), rng.uniform(-1, 1, vig.shape)
    got = eng.vjp(x, g_psf, g_vig)
    assert eng.last["fallback"] is None and eng.one_pass == 1
    want = (jp * g_psf).reshape(len(x), -1).sum(1) + (jv * g_vig).reshape(len(x), -1).sum(1)
    assert np.linalg.norm(got - want) / np.linalg.norm(want) <= 5e-3


@pytest.mark.slow
def test_the_one_pass_gradient_over_the_wide_space(sur):
    """Designs drawn over the paper's Table 1 widths (paper-triplet-wide: radii +-13-22 %, conics
    +-0.4, air gaps up to +-100 %), manufacturable (the dataset's sampler, seed 11), traced as
    the e2e dataset traces them. Where the engine has a one-pass gradient, J^T g against the
    Jacobian by differences (steps 1e-4 of each range): measured 5e-5; asserted <= 0.5 %.
    Where it has none, it says why: of the first six draws three have it; two are PSFs whose
    pupil does not fit the general FFT's direction grid, one a pupil traced cell by cell."""
    from optix_e2e.lens_design.constraints import Limits
    from optix_e2e.lens_design.sampling import sample_designs
    from optix_e2e.lens_design.space import load_space

    space, base = load_space("paper-triplet-wide")
    assert space.names == [p["name"] for p in sur.manifest["space"]["parameters"]]
    wide = {"source": space.source, "lens": space.lens_ref, "constraints": space.constraints}
    man = {**sur.manifest, "space": {**wide, "parameters": space.to_json()}}
    lo, hi = np.array([p.min for p in space.params]), np.array([p.max for p in space.params])
    draws = sample_designs(space, base, 2, seed=11, limits=Limits.from_dict(space.constraints)).values
    rng = np.random.default_rng(4)
    eng = ExactOptics(man, sur.psf_kind, sur.bin, lo, hi)
    g_psf, g_vig = rng.uniform(-1, 1, (13, 3, 41, 41)), rng.uniform(-1, 1, (13, 3))
    # the first draw: no one-pass gradient, and the reason names the PSF
    eng.psfs(draws[0])
    grad, why = eng._one_pass(draws[0], g_psf, g_vig)
    assert grad is None and "does not fit in the direction grid" in why
    # the second: one pass, against the Jacobian
    eng.steps = 1e-4 * (hi - lo)
    psf, vig, jp, jv = eng.jacobian(draws[1])
    got = eng.vjp(draws[1], g_psf, g_vig)
    assert eng.last["fallback"] is None
    want = (jp * g_psf).reshape(len(lo), -1).sum(1) + (jv * g_vig).reshape(len(lo), -1).sum(1)
    assert np.linalg.norm(got - want) / np.linalg.norm(want) <= 5e-3


def test_the_one_pass_gradient_of_the_fine_psfs_binned(sur):
    """The other PSF kind and a binning: the fine PSFs (123 px at 2 um) summed over 3 x 3 blocks
    (the backward pass spreads dL/dPSF back over each block before the engine's transpose of its
    normalization). Measured 3.3e-4 against the Jacobian (steps 3e-4 of each range)."""
    eng = ExactOptics(sur.manifest, "psf", 3, sur.param_min.double().numpy(), sur.param_max.double().numpy())
    eng.steps = 3e-4 * (eng.hi - eng.lo)
    v = DifferentiableOptics(sur).base_values().double().numpy()
    psf, vig, jp, jv = eng.jacobian(v)
    assert psf.shape == (13, 3, 41, 41)
    rng = np.random.default_rng(1)
    g_psf, g_vig = rng.uniform(-1, 1, psf.shape), rng.uniform(-1, 1, vig.shape)
    got = eng.vjp(v, g_psf, g_vig)
    assert eng.last["fallback"] is None
    want = (jp * g_psf).reshape(len(v), -1).sum(1) + (jv * g_vig).reshape(len(v), -1).sum(1)
    assert np.linalg.norm(got - want) / np.linalg.norm(want) <= 5e-3


def test_a_design_without_a_one_pass_gradient_falls_back_to_differences_and_says_why(sur, monkeypatch):
    """Where the engine has no one-pass gradient for the design (here: a manifest whose PSFs are
    the general FFT's), the step is the Jacobian's, counted, with the engine's reason."""
    man = {**sur.manifest, "settings": {**sur.manifest["settings"], "psf_method": "huygens"}}
    eng = ExactOptics(man, sur.psf_kind, sur.bin, sur.param_min.double().numpy(), sur.param_max.double().numpy())
    k, c, s = len(man["fields_deg"]), len(man["channels"]), man["sensor_size"]
    calls = []

    def jacobian(v):
        calls.append(v)
        return None, None, np.ones((len(v), k, c, s, s)), np.ones((len(v), k, c))

    monkeypatch.setattr(eng, "jacobian", jacobian)
    monkeypatch.setattr(eng, "psfs", lambda v: None)
    eng._cache = (None, None, None, float(sur.manifest["base_lens"]["surfaces"][-1]["thickness"]))
    v = DifferentiableOptics(sur).base_values().double().numpy()
    g = eng.vjp(v, np.full((k, c, s, s), 2.0), np.full((k, c), 3.0))
    assert len(calls) == 1 and eng.fallbacks == 1 and eng.one_pass == 0
    np.testing.assert_allclose(g, 2.0 * k * c * s * s + 3.0 * k * c)
    assert "huygens" in eng.last["fallback"], eng.last


def test_an_engine_error_or_a_non_finite_one_pass_gradient_falls_back_too(nominal_jacobian, monkeypatch):
    """The forward pass computed the design, so a failure of its one-pass gradient (an engine
    error in the tangents) or a non-finite one is a fallback with its reason, never a NaN."""
    from optix_e2e import engine

    eng, v, psf, vig, jp, jv = nominal_jacobian
    g_psf, g_vig = np.ones(psf.shape), np.ones(vig.shape)
    want = (jp * g_psf).reshape(len(v), -1).sum(1) + (jv * g_vig).reshape(len(v), -1).sum(1)
    for bad in ("error", "nan"):

        def vjp(*args, bad=bad):
            if bad == "error":
                raise engine.TraceError("chief ray at 14.9 deg: missed at surface 5")
            return {"fallback": None, "grad": np.full(len(v), np.nan)}

        monkeypatch.setattr(ExactOptics, "_engine_vjp", staticmethod(vjp))
        n = eng.fallbacks
        got = eng.vjp(v, g_psf, g_vig)
        assert eng.fallbacks == n + 1 and np.isfinite(got).all()
        np.testing.assert_allclose(got, want, rtol=1e-12)
        assert ("missed at surface 5" if bad == "error" else "not finite") in eng.last["fallback"]


@pytest.mark.slow
def test_exact_lens_gradient_agrees_with_the_surrogate_in_sign(sur):
    """A task-like loss (L1 of a textured image through the lens against the sharp image): the
    exact backend's gradient w.r.t. the optimizer's coordinates agrees in sign with the
    surrogate's on every parameter holding at least 5 % of the largest component (measured:
    13 of 19; cosine 0.9999)."""
    g = torch.Generator().manual_seed(0)
    img = torch.nn.functional.avg_pool2d(torch.rand(1, 3, 96, 96, generator=g), 3, 1, 1)
    grads = {}
    for backend in ("exact", "surrogate"):
        o = DifferentiableOptics(sur, backend=backend)
        ((o(img) - img).abs().mean()).backward()
        grads[backend] = o.u.grad.double().numpy()
    e, s = grads["exact"], grads["surrogate"]
    assert np.isfinite(e).all() and np.abs(e).max() > 0
    dominant = np.abs(e) >= 0.05 * np.abs(e).max()
    assert dominant.sum() >= 5
    assert np.all(np.sign(e[dominant]) == np.sign(s[dominant])), [
        (n, a, b) for n, a, b, d in zip(sur.param_names, e, s, dominant) if d
    ]
    assert float(e @ s / np.linalg.norm(e) / np.linalg.norm(s)) > 0.9


def test_a_design_the_engine_rejects_is_a_named_error_not_nan(sur):
    eng = ExactOptics.from_surrogate(sur)
    v = DifferentiableOptics(sur).base_values().double().numpy()
    i = eng.names.index("s_1_radius")
    bad = v.copy()
    bad[i] = 0.5  # a 0.5 mm radius on a 12 mm aperture: rays miss the surface
    with pytest.raises(EngineRejectedDesign, match="s_1_radius=0.5"):
        eng.psfs(bad)
    eng.steps = np.full(len(v), 1e-3)
    with pytest.raises(EngineRejectedDesign, match="rejects the design"):
        eng.jacobian(bad)
    x = torch.tensor(bad, requires_grad=True)
    with pytest.raises(EngineRejectedDesign):
        exact_psfs(x, eng)


def test_one_rejected_side_gives_the_one_sided_difference_and_both_a_named_error(sur, monkeypatch):
    eng = ExactOptics.from_surrogate(sur)
    v = DifferentiableOptics(sur).base_values().double().numpy()
    p = len(v)
    eng.steps = 1e-3 * (eng.hi - eng.lo)
    real_run = eng._run
    drop = {}

    def run(values, image=None):
        psf, vig, reasons = real_run(values, image)
        for k in drop:
            psf[k], vig[k] = None, None
            reasons[k] = drop[k]
        return psf, vig, reasons

    monkeypatch.setattr(eng, "_run", run)
    i = eng.names.index("l_12")
    _, _, jp_ref, _ = eng.jacobian(v)
    drop[1 + i] = "rays miss surface 3"  # the + side of l_12
    psf0, vig0, jp, jv = eng.jacobian(v)
    assert eng.last["one_sided"] == ["l_12"]
    minus = real_run((v - np.eye(p)[i] * eng.steps[i])[None])[0][0]
    np.testing.assert_allclose(jp[i], (psf0 - minus) / eng.steps[i], rtol=1e-12, atol=1e-12)
    # the one-sided column is close to the central one (first order in h)
    assert np.abs(jp[i] - jp_ref[i]).sum() < 0.1 * np.abs(jp_ref[i]).sum()
    drop[1 + p + i] = "rays miss surface 3"  # and the - side
    with pytest.raises(EngineRejectedDesign, match="no derivative in l_12.*rays miss surface 3"):
        eng.jacobian(v)


def test_render_with_fewer_field_samples(sur):
    o = DifferentiableOptics(sur)
    o.use_fields(4)
    assert o.field_index == [0, 4, 8, 12]
    img = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        out4 = o(img)
        o.use_fields(0)
        out13 = o(img)
    assert out4.shape == out13.shape and torch.isfinite(out4).all()
    assert 0 < float((out4 - out13).abs().mean()) < 0.05 * float(out13.abs().mean())
    with pytest.raises(ValueError, match="field samples"):
        o.use_fields(1)


def test_a_step_choice_with_rejected_rungs_is_json_safe():
    """A rung whose designs the engine rejects leaves no estimate (inf inside, null in JSON):
    results.json (written with allow_nan=False) and the resume state take it."""
    import json

    from optix_e2e.optics.exact import StepChoice

    sc = StepChoice(
        ["a", "b"],
        np.array([1e-3, 2e-3]),
        [1e-2, 1e-3, 1e-4],
        np.array([1e-4, np.inf]),
        np.array([[1e-3, 1e-4], [np.inf, np.inf]]),
    )
    d = json.loads(json.dumps(sc.to_json(), allow_nan=False))
    assert d["rel_error"] == [1e-4, None] and d["curves"][1] == [None, None]
    back = StepChoice.from_json(d)
    assert np.array_equal(back.steps, sc.steps) and np.isinf(back.rel_error[1]) and back.curves.shape == (2, 2)


def test_sides_beyond_a_range_bound_are_not_computed(sur):
    """Next to a bound the Jacobian is one-sided there and the outside design is never run."""
    eng = ExactOptics.from_surrogate(sur)
    v = DifferentiableOptics(sur).base_values().double().numpy()
    i = eng.names.index("l_12")
    eng.steps = 1e-3 * (eng.hi - eng.lo)
    v[i] = eng.hi[i] - 0.5 * eng.steps[i]  # the + side would leave the range
    _, _, jp, _ = eng.jacobian(v)
    assert eng.last["one_sided"] == ["l_12"] and eng.last["designs"] == 2 * len(v)
    assert np.isfinite(jp).all()
