"""One definition of a manufacturable lens (optix_e2e.lens_design.constraints): the design
sampler, the design run's guard and its final checks give the same verdict on random designs,
each checked at its own clear apertures; the rule of the older datasets (the base lens's
apertures for every design) does not."""

from __future__ import annotations

import numpy as np
import pytest

from optix_e2e.camera_design.guard import Manufacturable
from optix_e2e.camera_design.outputs import check_final_design
from optix_e2e.lens import Lens
from optix_e2e.lens.apertures import engine_base
from optix_e2e.lens_design.constraints import REASONS, ApertureError, Limits, Manufacturability, apertures
from optix_e2e.lens_design.sampling import sample_designs
from optix_e2e.surrogate import OpticsSurrogate

M = 48  # random designs of the space, every one checked by each tool


@pytest.fixture(scope="module")
def e2e_space():
    """The bundled end-to-end surrogate's manifest (what the guard reads), its space, base
    lens, limits, and M uniform draws of the space (the sampler's stream for seed 11)."""
    man = OpticsSurrogate.load("paper-triplet-e2e").manifest
    from optix_e2e.dataset.manifest import space_and_base

    space, base = space_and_base(man)
    limits = Limits.from_dict(man["sampling_summary"]["limits"])
    lo = np.array([p.min for p in space.params])
    span = np.array([p.max - p.min for p in space.params])
    draws = lo + np.random.Generator(np.random.PCG64(11)).random((M, len(space))) * span
    return man, space, base, limits, draws


def test_sampler_guard_and_final_checks_agree_on_random_designs(e2e_space):
    man, space, base, limits, draws = e2e_space
    guard = Manufacturable(man)
    z = float(base.data["surfaces"][-1]["thickness"])  # the base's image plane, as the sampler and guard check
    by_guard = [not guard.problems(x) for x in draws]
    by_final = [check_final_design(man, x, z)["manufacturable"] for x in draws]
    assert by_guard == by_final
    assert 0 < sum(by_guard) < M  # the limits bind in this space: both verdicts occur
    # the sampler, on the same stream: it accepts exactly the draws the guard accepts
    k = sum(by_guard)
    res = sample_designs(space, base, k, seed=11, method="uniform", limits=limits, apertures="auto")
    last = int(np.flatnonzero(by_guard)[-1])
    assert res.drawn == last + 1 and res.n_rejected == last + 1 - k
    np.testing.assert_array_equal(res.values, draws[np.flatnonzero(by_guard)])


def test_the_older_rule_accepts_designs_the_guard_refuses(e2e_space):
    """The base lens's clear apertures for every design (the datasets made before the one
    definition): designs whose own rims are wider pass it and fail the guard."""
    man, space, base, limits, draws = e2e_space
    guard = Manufacturable(man)
    old = sample_designs(space, base, 20, seed=11, method="uniform", limits=limits, apertures="base-lens")
    refused = [x for x in old.values if guard.problems(x)]
    assert refused and all("edge_thickness" in guard.problems(x) for x in refused)


def test_each_design_is_checked_at_its_own_clear_apertures():
    """Opening the aperture widens the footprint at every element: the same glass that passes
    at f/4.4 (its first element 0.001 mm above the 2 mm edge limit) fails it at f/3.5."""
    lens = Lens.load("paper-triplet")
    traced = engine_base(lens, "auto")
    rule = Manufacturability(Limits(min_edge=2.0))
    assert rule.problems(traced) == []
    wide = engine_base(lens, "auto")
    wide["aperture"] = {**wide["aperture"], "value": 3.5}
    sd, sd_wide = apertures(Lens(traced, source="a")), apertures(Lens(wide, source="b"))
    assert np.all(sd_wide[:2] > sd[:2] * 1.05)  # the first element's rims (7.15 -> 7.85 mm in front)
    assert "edge_thickness" in rule.problems(wide)
    assert rule.checks == 2 and set(REASONS) >= {"edge_thickness", "untraceable"}


def test_a_design_that_cannot_be_sized_is_refused_with_its_reason():
    """A 2 mm sphere in front of a 5.7 mm beam: its rim crosses the next surface inside the
    beam, so there is no footprint to check; the reason says so, no exception escapes."""
    lens = Lens.load("paper-triplet")
    d = engine_base(lens, "auto")
    d["surfaces"][0]["radius"] = 2.0
    rule = Manufacturability(Limits())
    problems = rule.problems(d)
    assert len(problems) == 1 and problems[0].startswith("surfaces_cross: "), problems
    with pytest.raises(ApertureError, match="^surfaces_cross: "):
        rule.margins(d)


def test_a_design_no_ray_of_some_field_reaches_is_refused_as_the_engine_would():
    """A sampled design of paper-triplet-detect-wide that passes every limit, but at 14.9 deg,
    470 nm no ray reaches the image (at 600 nm the chief ray misses): the engine refuses that
    field's PSF, so the one
    definition calls it untraceable and the sampler does not draw it (the datasets then hold no
    refused design of this kind)."""
    import json
    from pathlib import Path

    from optix_e2e import _engine
    from optix_e2e.engine import TraceError

    path = Path(__file__).parents[1] / "data" / "lenses" / "detect_wide_unreached.json"
    d = json.loads(path.read_text())
    problems = Manufacturability(Limits()).problems(d)
    assert len(problems) == 1 and problems[0].startswith("untraceable: the chief ray at 14.9 deg"), problems
    lens = Lens(d)
    with pytest.raises(TraceError, match="chief ray at 14.9 deg"):
        _engine.psf_rgb(lens.to_engine_json(), 14.9, lens.rgb_channels(), method="fft", size=16)
    assert Manufacturability(Limits()).problems(engine_base(Lens.load("paper-triplet"), "auto")) == []


def test_the_chief_ray_status_of_every_field_in_one_call_is_each_fields_own_trace():
    """engine.chief_ray_status (the check's one call) gives, field by field and wavelength by
    wavelength, the status of that field's own chief-ray trace, and the engine's message
    where a beam cannot be launched (a wavelength the glass does not cover)."""
    import json
    from pathlib import Path

    import numpy as np

    from optix_e2e import engine

    path = Path(__file__).parents[1] / "data" / "lenses" / "detect_wide_unreached.json"
    lens = Lens(json.loads(path.read_text()))
    fields, wls = [0.0, 7.0, 12.7, 14.9], [470.0, 550.0, 600.0, 650.0, 5000.0]
    got = engine.chief_ray_status(lens.to_engine_json(), fields_deg=fields, wavelengths_nm=wls)
    assert len(got) == len(fields) * len(wls)
    zero = np.zeros(1)
    for k, st in enumerate(got):
        f, wl = fields[k // len(wls)], wls[k % len(wls)]
        try:
            own = int(lens.trace_field(f, zero, zero, wavelength_nm=wl)["status"][0])
        except engine.EngineError as err:
            assert isinstance(st, str) and st.split(":")[-1].strip() in str(err), (f, wl, st, err)
            continue
        assert st == own, (f, wl, st, own)
    assert 1 in got and 0 in got and any(isinstance(s, str) for s in got), got


def test_the_footprint_in_one_call_is_the_largest_height_of_each_fields_own_paths():
    """engine.ray_footprint (the clear apertures' one call) equals the largest radial height,
    surface by surface, of the rays of each field's own trace_field_path that reach the image,
    at two wavelengths, and raises what that trace raises (a wavelength the glass lacks)."""
    import numpy as np

    from optix_e2e import engine

    lens = Lens.load("paper-triplet")
    js, k = lens.to_engine_json(), len(lens.surfaces)
    t = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    px, py = np.append(np.sin(t), 0.0), np.append(np.cos(t), 0.0)
    fields, wls = [0.0, 10.0, 14.9, 40.0], [470.0, 650.0]  # at 40 deg some rays miss
    want = np.zeros(k)
    for f in fields:
        for wl in wls:
            d = engine.trace_field_path(js, field_deg=f, px=px, py=py, wavelength_nm=wl)
            ok = d["status"] == 0
            if ok.any():
                p = d["path"][ok, :k]
                want = np.maximum(want, np.hypot(p[..., 0], p[..., 1]).max(axis=0))
    got = engine.ray_footprint(js, n_surfaces=k, fields_deg=fields, wavelengths_nm=wls, px=px, py=py)
    assert np.array_equal(got, want) and (got > 0).all()
    with pytest.raises(engine.EngineError) as one:
        engine.trace_field_path(js, field_deg=0.0, px=px, py=py, wavelength_nm=5000.0)
    with pytest.raises(engine.EngineError) as both:
        engine.ray_footprint(js, n_surfaces=k, fields_deg=fields, wavelengths_nm=[5000.0], px=px, py=py)
    assert str(both.value) == str(one.value)
