"""Layout, spot diagrams, report and the ``plot``/``report`` commands (optix_e2e.lens_design.analysis,
optix_e2e.lens_design.report, optix_e2e.lens_design.plots, cli/lens_report.py), and the engine's ray paths (trace_field_path).

Geometry is checked against closed forms (sphere, parabola and asphere sags) and against
the engine: every path point lies on the Python sag of its surface to 1e-12 mm, which
ties the drawn profiles to the traced rays.
"""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from optix_e2e import _engine
from optix_e2e.cli.lens_report import plot, report
from optix_e2e.lens import Lens
from optix_e2e.lens.mtf import field_mtf
from optix_e2e.lens.surface import sag
from optix_e2e.lens_design.analysis import footprint, hexapolar, spot_diagram, surface_geometry

ASPHERIC = {
    "name": "asph-test",
    "aperture": {"type": "epd", "value": 8},
    "fields_deg": [0, 10],
    "wavelengths_nm": [486.1, 587.6, 656.3],
    "surfaces": [
        {
            "radius": 14,
            "conic": -0.6,
            "aspheric": {"a4": -2e-5, "a6": 1e-7},
            "thickness": 5,
            "material": "N-BK7",
            "semi_diameter": 6,
        },
        {"radius": "inf", "thickness": 2, "material": "air", "semi_diameter": 6},
        {"radius": 25, "conic": 0.5, "thickness": 3, "material": {"n": 1.6}, "stop": True, "semi_diameter": 4.5},
        {"radius": -40, "aspheric": {"a4": 3e-5}, "thickness": 18, "material": "air", "semi_diameter": 5},
    ],
}


def test_sag_closed_forms():
    r = np.linspace(-4, 4, 9)
    assert sag({"radius": 10.0}, r) == pytest.approx(10 - np.sqrt(100 - r**2), abs=1e-13)
    assert sag({"radius": -10.0}, r) == pytest.approx(-(10 - np.sqrt(100 - r**2)), abs=1e-13)
    assert sag({"radius": 20.0, "conic": -1.0}, r) == pytest.approx(r**2 / 40, abs=1e-13)  # parabola
    asph = {"curvature": 0.0, "aspheric": {"a4": 1e-3, "a6": -2e-5}}
    assert sag(asph, r) == pytest.approx(1e-3 * r**4 - 2e-5 * r**6, abs=1e-13)
    assert sag({"radius": "inf"}, r) == pytest.approx(0 * r)
    assert np.isnan(sag({"radius": 2.0}, [3.0])[0])  # beyond the hemisphere


@pytest.mark.parametrize("which", ["cooke", "aspheric"])
def test_paths_lie_on_the_drawn_profiles(cooke, which):
    lens = cooke if which == "cooke" else Lens(ASPHERIC)
    k = len(lens.surfaces)
    z0 = np.cumsum([0.0] + [float(s["thickness"]) for s in lens.surfaces])
    py = np.linspace(-1.4, 1.4, 15)  # beyond the pupil too: some rays fail
    for field in lens.fields_deg:
        for aiming in ("paraxial", "real"):
            d = _engine.trace_field_path(
                lens.to_engine_json(), field, np.zeros_like(py), py, lens.primary_wavelength_nm, aiming
            )
            plain = lens.trace_field(field, np.zeros_like(py), py, aiming=aiming)
            assert d["path"].shape == (py.size, k + 1, 3) and np.all(np.isfinite(d["path"]))
            np.testing.assert_array_equal(d["status"], plain["status"])
            for j in range(py.size):
                last = d["last"][j]
                if plain["status"][j] == 0:
                    assert last == k
                    assert np.array_equal(d["path"][j, k], plain["position"][j])  # bit for bit
                assert np.all(d["path"][j, last + 1 :] == 0.0)
                for i in range(min(last + 1, k)):
                    x, y, z = d["path"][j, i]
                    assert z - z0[i] == pytest.approx(float(sag(lens.surfaces[i], np.hypot(x, y))), abs=1e-12)
    with pytest.raises(ValueError, match="differ in length"):
        _engine.trace_field_path(lens.to_engine_json(), 0.0, np.zeros(3), np.zeros(2), 550.0)


def test_clipped_rays_stop_on_the_clipping_surface():
    lens = Lens(ASPHERIC)
    py = np.array([-1.6, -1.0, 0.0, 1.0, 1.6])
    d = _engine.trace_field_path(lens.to_engine_json(), 10.0, np.zeros(5), py, 587.6)
    clipped = np.flatnonzero(d["status"] == 2)
    assert clipped.size >= 1
    for j in clipped:
        i = d["surface"][j]
        assert d["last"][j] == i
        assert np.hypot(*d["path"][j, i, :2]) > lens.surfaces[i]["semi_diameter"]


def test_geometry_uses_clear_apertures_or_the_footprint(cooke):
    fp = footprint(cooke, cooke.fields_deg)
    geo = surface_geometry(cooke, fp)
    assert [g["glass_after"] for g in geo] == [True, False, True, False, True, False]
    assert [g["stop"] for g in geo] == [False, False, False, True, False, False]
    # On axis, surface 1 is met by the marginal ray at EPD/2 exactly (a beam parallel to
    # the axis); at the stop the real marginal ray is within 2% of the paraxial stop
    # semi-diameter (pupil spherical aberration: 3.857 vs 3.801 mm).
    on_axis = footprint(cooke, [0.0])
    assert on_axis[0] == pytest.approx(cooke.paraxial()["epd_mm"] / 2, abs=1e-12)
    assert on_axis[3] <= fp[3]
    assert on_axis[3] == pytest.approx(cooke.paraxial()["stop_semi_diameter_mm"], rel=0.02)
    # Rays that fail (at 35 deg every ray misses surface 4 or is totally reflected
    # there) do not size the surfaces.
    np.testing.assert_array_equal(footprint(cooke, [0.0, 20.0, 35.0]), footprint(cooke, [0.0, 20.0]))
    asph = Lens(ASPHERIC)
    assert [g["semi_diameter"] for g in surface_geometry(asph, footprint(asph, [0.0]))] == [6, 6, 4.5, 5]


def test_spot_diagram_is_centroid_referenced(cooke):
    for field in cooke.fields_deg:
        s = spot_diagram(cooke, field)
        pts = np.concatenate(s["points_um"])
        assert np.abs(pts.mean(axis=0)).max() < 1e-9
        # The plotted hexapolar grid (12 rings), each point weighted by its pupil area
        # (the rim ring covers a half-width annulus), gives the engine's dense RMS
        # (64 rings) within 1.5% (measured 0.3-1.0%).
        rings = 12
        area = [np.pi * (0.5 / rings) ** 2] + [
            np.pi * (min((k + 0.5) / rings, 1) ** 2 - ((k - 0.5) / rings) ** 2) / (6 * k)
            for k in range(1, rings + 1)
            for _ in range(6 * k)
        ]
        w = np.tile(area, len(s["points_um"]))
        assert np.sqrt((w * (pts**2).sum(axis=1)).sum() / w.sum()) == pytest.approx(s["rms_um"], rel=0.015)
        assert s["centroid_um"][1] * 1e-3 == pytest.approx(s["chief_y_mm"], abs=0.05)
    px, py = hexapolar(3)
    assert px.size == 1 + 6 + 12 + 18 and np.hypot(px, py).max() == pytest.approx(1.0)


def test_plot_command_draws_every_ray(tmp_path, cooke):
    out = tmp_path / "layout.png"
    res = CliRunner().invoke(plot, ["cooke-f50", "--out", str(out), "--rays", "7", "--fields", "0,10,20"])
    assert res.exit_code == 0, res.output
    line = json.loads(res.output)
    assert [f["reached_image"] for f in line["fields"]] == [7, 7, 7]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from optix_e2e.lens_design.plots import save_layout_png

    r = save_layout_png(tmp_path / "again.png", cooke, fields=[0, 10, 20], rays=7)
    (x0, x1), (y0, y1) = r["xlim"], r["ylim"]
    for fan in r["fans"]:
        for pts in fan["rays"]:
            assert x0 < r["z_start"] and pts[:, 0].max() < x1
            assert y0 < pts[:, 1].min() and pts[:, 1].max() < y1
    r35 = save_layout_png(tmp_path / "tir.png", cooke, fields=[0, 35], rays=5)
    assert r35["fans"][1]["n_image"] == 0 and not any(r35["fans"][1]["ok"]) and all(r35["fans"][0]["ok"])
    w, h = r["size_px"]
    assert 1.3 < w / h < 3.5  # equal aspect for a 60 mm long, ~40 mm tall drawing


def test_report_command_writes_figures_and_json(tmp_path, cooke):
    out = tmp_path / "rep"
    res = CliRunner().invoke(report, ["cooke-f50", "--out", str(out), "--freqs", "20,85.32"])
    assert res.exit_code == 0, res.output
    assert "MTF 20 deg" in res.stderr and "wrote" in res.stderr
    for name in ("layout.png", "spots.png", "mtf.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    rep = json.loads((out / "report.json").read_text())
    assert rep["paraxial"]["efl_mm"] == pytest.approx(50.0, abs=1e-3)
    assert [f["field_deg"] for f in rep["fields"]] == cooke.fields_deg
    ref = field_mtf(cooke, 14.0, [85.32])
    row = rep["fields"][1]
    assert row["mtf"]["85.32"]["tangential"] == pytest.approx(ref["tangential"][0], abs=1e-12)
    assert row["mtf"]["85.32"]["sagittal"] == pytest.approx(ref["sagittal"][0], abs=1e-12)
    # Alone, 650 nm is sampled at its own pixel (lambda N / 4), not 480 nm's: same MTF
    # within the method's error.
    mono = field_mtf(cooke, 14.0, [85.32], wavelengths_nm=[650.0])
    assert row["mtf_per_wavelength"]["650"]["85.32"]["sagittal"] == pytest.approx(mono["sagittal"][0], abs=1e-3)
    assert row["relative_illumination"] == pytest.approx(cooke.spot(14.0)["relative_illumination"], abs=1e-12)
    assert rep["fields"][0]["rms_spot_um"] == pytest.approx(cooke.spot(0.0)["rms_um"], abs=1e-12)
    # the report records its own wall time (a figure for benches, not a test: the machine is shared)
    assert math.isfinite(rep["time_s"]) and rep["time_s"] > 0


@pytest.mark.parametrize(
    "args, code, message",
    [
        (["no-such-lens"], 1, "neither a lens file nor a bundled lens"),
        (["cooke-f50", "--fields", "0,95"], 2, "[0, 90)"),
        (["cooke-f50", "--fields", "a"], 2, "comma-separated"),
        (["cooke-f50", "--freqs", "10,5000"], 1, "MTF frequencies must lie in"),
    ],
)
def test_report_command_rejects_bad_input(tmp_path, args, code, message):
    out = tmp_path / "bad"
    res = CliRunner().invoke(report, args + ["--out", str(out)])
    assert res.exit_code == code and message in res.output, res.output
    assert not out.exists()  # nothing half-written
