"""The classic optimizer (optix_e2e.lens_design.optimizer), parameter spaces (optix_e2e.lens_design.space) and the
``optimize`` CLI command.

Reference values: the engine's own hexapolar spot statistics (an independent sampling of
the same RMS spot), closed-form disk moments and sphere sags, and the published Cooke
triplet (bundled cooke-f50) whose merit the optimizer must recover from a perturbed start.
"""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from optix_e2e.cli.lens_optimize import optimize_cmd
from optix_e2e.lens import BUNDLED_DIR, Lens
from optix_e2e.lens.pupil import pupil_quadrature
from optix_e2e.lens_design.optimizer import Constraints, Merit, element_geometry, optimize, sag
from optix_e2e.lens_design.space import ParameterSpace, SpaceError, parameter_from_name


@pytest.fixture(scope="module")
def cooke_raw() -> dict:
    return json.loads((BUNDLED_DIR / "cooke-f50.json").read_text())


@pytest.fixture(scope="module")
def cooke(cooke_raw) -> Lens:
    return Lens(cooke_raw)


# ----- merit --------------------------------------------------------------------------
def test_quadrature_integrates_disk_moments():
    px, py, w = pupil_quadrature(4, 8)
    r2 = px**2 + py**2
    assert w.sum() == pytest.approx(1.0, abs=1e-14)
    # mean over the unit disk of rho^(2m) is 1/(m+1); of x^2 is 1/4; of x^2 y^2 is 1/24
    for m in (1, 2, 3, 4):
        assert (w * r2**m).sum() == pytest.approx(1.0 / (m + 1), rel=1e-12)
    assert (w * px**2).sum() == pytest.approx(0.25, rel=1e-12)
    assert (w * px**2 * py**2).sum() == pytest.approx(1.0 / 24.0, rel=1e-12)


def test_merit_matches_engine_spot(cooke):
    """Per-field RMS of the 6x12 quadrature merit vs the engine's 128-ring hexapolar spot."""
    rep = Merit(cooke).evaluate(cooke.data)
    for row in rep["fields"]:
        ref = cooke.spot(row["field_deg"], rings=128)["rms_um"]
        assert row["rms_spot_um"] == pytest.approx(ref, rel=2e-3)
    # merit = quadrature mean of the per-field mean squares (equal field weights)
    ms = np.mean([r["rms_spot_um"] ** 2 for r in rep["fields"]])
    assert rep["merit_um"] == pytest.approx(math.sqrt(ms), rel=1e-9)


def test_field_weights_change_merit(cooke):
    rep = Merit(cooke, field_weights=[0, 0, 1]).evaluate(cooke.data)
    assert rep["merit_um"] == pytest.approx(rep["fields"][2]["rms_spot_um"], rel=1e-9)
    with pytest.raises(ValueError, match="field weights"):
        Merit(cooke, field_weights=[1, 1])


def test_failed_rays_are_penalized_not_nan(cooke_raw):
    raw = copy.deepcopy(cooke_raw)
    raw["surfaces"][0]["semi_diameter"] = 3.0  # clips part of the 10 mm beam
    rep = Merit(Lens(raw)).evaluate(Lens(raw).data)
    assert rep["failed_rays"] > 0
    assert np.all(np.isfinite(rep["residuals"]))
    assert np.max(np.abs(rep["residuals"])) > 0.01


# ----- geometry -----------------------------------------------------------------------
def test_sag_closed_forms():
    r = np.array([0.0, 1.0, 3.0, 4.5])
    R = 12.0
    sphere = R - np.sqrt(R * R - r * r)
    assert np.allclose(sag({"radius": R}, r), sphere, atol=1e-13)
    # paraboloid (k = -1): r^2 / 2R; plus an a4 term
    assert np.allclose(
        sag({"radius": R, "conic": -1.0, "aspheric": {"a4": 1e-4}}, r), r * r / (2 * R) + 1e-4 * r**4, atol=1e-13
    )
    assert np.allclose(sag({"radius": "inf"}, r), 0.0)


def test_element_geometry_biconvex_and_stop():
    lens = {
        "surfaces": [
            {"radius": 20.0, "thickness": 5.0, "material": {"n": 1.5}},
            {"radius": -20.0, "thickness": 2.0, "material": "air"},
            {"radius": "inf", "thickness": 3.0, "material": "air", "stop": True},
            {"radius": -30.0, "thickness": 2.0, "material": {"n": 1.7}},
            {"radius": 30.0, "thickness": 10.0, "material": "air"},
        ]
    }
    h = 6.0
    s20 = 20.0 - math.sqrt(400.0 - 36.0)
    s30 = 30.0 - math.sqrt(900.0 - 36.0)
    geo = element_geometry(lens, [h, h, 2.0, h, h])
    g1, g2 = geo["glass"]
    assert g1["edge_mm"] == pytest.approx(5.0 - 2 * s20, abs=1e-12)
    assert g2["edge_mm"] == pytest.approx(2.0 + 2 * s30, abs=1e-12)
    (air,) = geo["air"]  # the stop plane does not split the gap
    assert air["center_mm"] == pytest.approx(5.0, abs=1e-12)
    assert air["edge_mm"] == pytest.approx(5.0 + s20 - s30, abs=1e-12)
    c1, c2 = geo["stop_clearance"]
    assert c1["edge_mm"] == pytest.approx(2.0 + s20, abs=1e-12)
    assert c2["edge_mm"] == pytest.approx(3.0 - s30, abs=1e-12)


def test_footprint_paraxial_limit_and_epd(cooke_raw, cooke):
    """For a tiny aperture the rim rays' heights on the (curved) stop surface tend to the
    paraxial stop semi-diameter; at full aperture the first surface sees the EPD radius."""
    raw = copy.deepcopy(cooke_raw)
    raw["aperture"] = {"type": "epd", "value": 0.05}
    raw["wavelengths_nm"] = [550.0]  # the paraxial data are at the primary wavelength
    small = Lens(raw)
    sd = Merit(small, fields_deg=[0.0]).footprint(small.data, small.to_engine_json())
    assert sd[3] == pytest.approx(small.paraxial()["stop_semi_diameter_mm"], rel=1e-4)
    sd = Merit(cooke, fields_deg=[0.0]).footprint(cooke.data, cooke.to_engine_json())
    assert sd[0] == pytest.approx(5.0, rel=1e-9)
    sd_all = Merit(cooke).footprint(cooke.data, cooke.to_engine_json())
    assert np.all(sd_all >= sd - 1e-9) and sd_all[0] > sd[0]


# ----- spaces -------------------------------------------------------------------------
def test_space_names_and_apply(cooke):
    sp = ParameterSpace.from_names("s_1_radius, s_1_conic, s_1_4th, s_2_thickness, s_3_thickness", cooke.data)
    assert [p.kind for p in sp.params] == ["radius", "conic", "asphere_4th", "air_gap", "thickness"]
    new = sp.apply(cooke.data, [25.0, -0.5, 1e-5, 6.5, 1.2])
    s = new["surfaces"]
    assert (s[0]["radius"], s[0]["conic"], s[0]["aspheric"]["a4"]) == (25.0, -0.5, 1e-5)
    assert (s[1]["thickness"], s[2]["thickness"]) == (6.5, 1.2)
    assert cooke.data["surfaces"][0]["radius"] == 22.01359  # input untouched
    assert sp.values(new) == [25.0, -0.5, 1e-5, 6.5, 1.2]


@pytest.mark.parametrize(
    "name, msg",
    [
        ("s_9_radius", "out of range"),
        ("s_1_5th", "asphere order"),
        ("radius_1", "expected s_N_radius"),
        ("s_1_4nd", "asphere order"),
    ],
)
def test_bad_parameter_names(cooke, name, msg):
    with pytest.raises(SpaceError, match=msg):
        parameter_from_name(name, cooke.data)


def test_space_file_errors_name_file_and_entry(tmp_path, cooke):
    bad = tmp_path / "bad.space.json"
    bad.write_text(json.dumps([{"name": "s_1_radius", "kind": "radius", "surface": 1, "min": -5, "max": 30}]))
    with pytest.raises(
        SpaceError, match=r"bad\.space\.json: parameters\[0\] \(s_1_radius\): a radius range may not contain 0"
    ):
        ParameterSpace.load(bad, cooke.data)
    bad.write_text(json.dumps([{"name": "x", "kind": "curv", "surface": 1, "min": 0, "max": 1}]))
    with pytest.raises(SpaceError, match=r"parameters\[0\] \(x\): kind 'curv'"):
        ParameterSpace.load(bad, cooke.data)
    bad.write_text('[{"name": 1,,]')
    with pytest.raises(SpaceError, match=r"bad\.space\.json:1:\d+: invalid JSON"):
        ParameterSpace.load(bad)


# ----- optimizer ----------------------------------------------------------------------
def test_recovers_perturbed_published_cooke(cooke_raw, cooke):
    """Issue 3's check: radii and spacings perturbed by up to 3 % (seed 1) and optimized
    back, the merit returns to within 1 % of the published design's (same merit)."""
    efl = cooke.paraxial()["efl_mm"]
    names = [f"s_{i}_radius" for i in range(1, 7)] + ["s_2_thickness", "s_4_thickness", "s_6_thickness"]
    sp = ParameterSpace.from_names(names, cooke.data)
    merit = Merit(cooke, Constraints(efl=efl, efl_tol=1e-4))
    published = merit.evaluate(cooke.data)["merit_um"]
    rng = np.random.default_rng(1)
    x0 = np.array(sp.values(cooke.data))
    start = sp.apply(cooke_raw, x0 * (1 + 0.03 * rng.uniform(-1, 1, len(x0))))
    perturbed = merit.evaluate(Lens(start).data)["merit_um"]
    assert perturbed > 3 * published  # the perturbation really spoils the design
    res = optimize(start, sp, merit, max_nfev=300)
    assert res.after["merit_um"] <= 1.01 * published, (res.after["merit_um"], published)
    assert all(c["ok"] for c in res.after["constraints"])
    assert res.after["paraxial"]["efl_mm"] == pytest.approx(efl, rel=1e-4)
    # catalog glass names survive in the written prescription
    assert res.lens["surfaces"][0]["material"] == cooke_raw["surfaces"][0]["material"]


def test_constraints_are_enforced(cooke_raw, cooke):
    """Ask for more than the published design gives: every air gap >= 5 mm (center and
    edge; its edge gaps are 4.6 and 3.8 mm) and glass edges >= 1.5 mm; the optimizer must
    meet them at the price of merit."""
    sp = ParameterSpace.from_names(
        [f"s_{i}_radius" for i in range(1, 7)]
        + ["s_1_thickness", "s_2_thickness", "s_4_thickness", "s_5_thickness", "s_6_thickness"],
        cooke.data,
    )
    c = Constraints(efl=50.0, min_air_gap=5.0, min_edge=1.5, min_bfd=30.0)
    merit = Merit(cooke, c, rings=3, arms=6)
    before = merit.evaluate(cooke.data)
    assert not all(r["ok"] for r in before["constraints"])
    res = optimize(cooke_raw, sp, merit, max_nfev=60)
    bad = [r for r in res.after["constraints"] if not r["ok"]]
    assert not bad, bad
    geo = element_geometry(Lens(res.lens).data, res.after["semi_diameters_mm"])
    assert min(g["edge_mm"] for g in geo["air"]) >= 5.0 - 1e-9
    assert min(g["edge_mm"] for g in geo["glass"]) >= 1.5 - 1e-9


def test_start_outside_bounds_is_an_error(cooke_raw, cooke):
    sp = ParameterSpace.from_names("s_1_radius", cooke.data)
    sp = ParameterSpace([type(sp.params[0])("s_1_radius", "radius", 1, 30.0, 40.0, "mm")])
    with pytest.raises(ValueError, match=r"s_1_radius = 22.0136 outside \[30, 40\]"):
        optimize(cooke_raw, sp, Merit(cooke))


# ----- CLI ----------------------------------------------------------------------------
def test_cli_optimize_writes_lens_and_summary(tmp_path):
    out = tmp_path / "opt.json"
    summ = tmp_path / "summary.json"
    r = CliRunner().invoke(
        optimize_cmd,
        [
            "cooke-f50",
            "--vars",
            "s_1_radius,s_6_radius,s_6_thickness",
            "--efl",
            "50",
            "--min-air-gap",
            "1",
            "--max-iter",
            "15",
            "--rings",
            "3",
            "--arms",
            "6",
            "--out",
            str(out),
            "--summary",
            str(summ),
            "--set-semi-diameters",
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(summ.read_text())
    assert summary["after"]["merit_um"] <= summary["before"]["merit_um"]
    assert set(summary["values"]) == {"s_1_radius", "s_6_radius", "s_6_thickness"}
    assert len(summary["after"]["fields"]) == 3
    lens = Lens.load(out)
    assert all(s["semi_diameter"] > 0 for s in lens.surfaces)
    assert lens.paraxial()["efl_mm"] == pytest.approx(50.0, rel=1e-3)


@pytest.mark.parametrize(
    "args, msg",
    [
        (["--vars", "s_1_radiuss"], "expected s_N_radius"),
        ([], "give the variables"),
        (["--vars", "s_12_radius"], "surface 12 out of range"),
    ],
)
def test_cli_optimize_errors(tmp_path, args, msg):
    r = CliRunner().invoke(optimize_cmd, ["cooke-f50", "--out", str(tmp_path / "o.json"), *args])
    assert r.exit_code != 0
    assert msg in r.output


def test_cli_space_file_and_paraxial_focus(tmp_path):
    """--space with the double Gauss's bundled space and the BFL solve: the result keeps
    every parameter in range and its image sits at its own paraxial focus."""
    out, summ = tmp_path / "dg.json", tmp_path / "dg.summary.json"
    space = BUNDLED_DIR / "spaces" / "double-gauss-f5.toml"
    r = CliRunner().invoke(
        optimize_cmd,
        [
            "double-gauss-f5",
            "--space",
            str(space),
            "--focus",
            "paraxial",
            "--efl",
            "100",
            "--max-iter",
            "4",
            "--rings",
            "3",
            "--arms",
            "6",
            "--out",
            str(out),
            "--summary",
            str(summ),
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(summ.read_text())
    assert summary["after"]["merit_um"] <= summary["before"]["merit_um"]
    lens = Lens.load(out)
    assert ParameterSpace.load(space, lens.data).check_bounds(lens.data) == []
    par = lens.paraxial()
    assert par["back_focus_shift_mm"] == pytest.approx(0.0, abs=1e-9)
    written = json.loads(out.read_text())  # catalog names kept as written
    assert written["surfaces"][3]["material"] == {"glass": "F5", "catalog": "schott"}
