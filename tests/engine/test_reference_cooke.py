"""The engine (through the bindings) against the optiland/rayoptics reference data for the
classic Cooke triplet in ../shared/reference."""

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

PRIMARY_NM = 550.0


def rel(a, b):
    return abs(a - b) / abs(b)


# ---------------------------------------------------------------- first order
@pytest.mark.parametrize(
    "ours, theirs",
    [
        ("efl_mm", "efl_mm"),
        ("bfl_mm", "bfl_mm_last_vertex_to_paraxial_focus"),
        ("epd_mm", "epd_mm"),
        ("f_number", "fno_paraxial"),
        ("total_track_mm", "total_track_first_vertex_to_image_mm"),
        ("xpd_mm", "xpd_mm"),
        ("entrance_pupil_z_mm", "entrance_pupil_pos_mm_rel_first_surface"),
        ("exit_pupil_z_mm", "exit_pupil_pos_mm_rel_image_plane"),
        ("paraxial_image_height_mm", "paraxial_image_height_f_tan_mm"),
    ],
)
def test_paraxial(cooke, ref_data, ours, theirs):
    par = cooke.paraxial(PRIMARY_NM)
    assert rel(par[ours], ref_data["first_order"][theirs]) < 1e-9, (par[ours], ref_data["first_order"][theirs])


def test_paraxial_defaults_to_primary_wavelength(cooke):
    assert cooke.paraxial() == cooke.paraxial(PRIMARY_NM)


# ---------------------------------------------------------------- RMS spot
SPOT_RINGS = 512  # ~790k rays per wavelength; the sampling error falls as 1/rings


def _converged_fields(ref_data):
    return [f for f in ref_data["per_field"] if "rms_spot_um_poly_converged" in f]


@pytest.mark.parametrize("field_deg", [0.0, 14.0, 20.0])
def test_poly_rms_spot_converged(cooke, ref_data, field_deg):
    ref = next(f for f in _converged_fields(ref_data) if f["field_deg"] == field_deg)
    s = cooke.spot(field_deg, rings=SPOT_RINGS)
    assert rel(s["rms_um"], ref["rms_spot_um_poly_converged"]) < 0.005, (s["rms_um"], ref)
    assert s["n_ok"] == s["n_rays"]  # no physical apertures: nothing is clipped
    assert s["chief_y_mm"] == pytest.approx(ref["chief_ray_image_y_mm"], abs=1e-9)


# Monochromatic: at 14 deg the reference's extrapolated 14.648 um sits 0.56% above our
# value, which converges as 1/rings^2 to 14.5667 um (rings 64/128/256/512: 14.5643,
# 14.5661, 14.5666, 14.5667) while our polychromatic figure at the same field matches the
# reference to 1e-5; we hold 0 and 20 deg to 0.5% and 14 deg to 1%.
@pytest.mark.parametrize("field_deg,tol", [(0.0, 0.005), (14.0, 0.01), (20.0, 0.005)])
def test_mono_rms_spot_converged(cooke, ref_data, field_deg, tol):
    ref = next(f for f in _converged_fields(ref_data) if f["field_deg"] == field_deg)
    s = cooke.spot(field_deg, wavelengths_nm=[PRIMARY_NM], rings=SPOT_RINGS)
    assert rel(s["rms_um"], ref["rms_spot_um_0p55_converged"]) < tol, (s["rms_um"], ref)


# The same monochromatic figures from optiland 0.6.3 itself, extrapolated properly: its
# hexapolar grid converges as 1/rings, so 2 * r(256) - r(128) (its CookeTriplet sample, 550 nm,
# paraxial aiming; `python benches/compare_optiland.py` prints them). They agree with ours to
# 2e-5 and put the reference file's 14.648 um (14 deg) and 11.3408 um (20 deg) ~0.5% high.
OPTILAND_MONO_EXTRAPOLATED_UM = {0.0: 4.1804, 14.0: 14.5668, 20.0: 11.2938}


@pytest.mark.parametrize("field_deg", [0.0, 14.0, 20.0])
def test_mono_rms_spot_matches_optiland_extrapolated(cooke, field_deg):
    s = cooke.spot(field_deg, wavelengths_nm=[PRIMARY_NM], rings=SPOT_RINGS)
    assert rel(s["rms_um"], OPTILAND_MONO_EXTRAPOLATED_UM[field_deg]) < 5e-4, s["rms_um"]


def test_spot_grid_converges_as_inverse_square_of_rings(cooke):
    r = [cooke.spot(14.0, wavelengths_nm=[PRIMARY_NM], rings=n)["rms_um"] for n in (32, 64, 128)]
    assert abs(r[2] - r[1]) < 0.35 * abs(r[1] - r[0])  # halves of the step would be 1/rings


def test_relative_illumination_on_axis_is_one(cooke):
    s = cooke.spot(0.0, rings=32)
    assert s["relative_illumination"] == pytest.approx(1.0, abs=1e-9)
    assert s["vignetting"] == pytest.approx(1.0, abs=1e-9)


# ---------------------------------------------------------------- Strehl
# The reference Strehl ratios are sampled peaks. On axis to 10 deg they are converged and
# our Strehl (refined peak over the same-pupil unaberrated peak) must agree within 2% for
# both methods. At 14 and 20 deg the reference FFT samples the peak at 1.4-1.5 um (and at
# 20 deg with one averaged f-number: its own 64-sample run gives 0.0985 against 0.0941),
# and the reference Huygens figures are normalized by the *on-axis* unaberrated peak, a
# different definition; there we check that our two methods agree with each other.
STREHL_FIELDS = [0.0, 7.0, 10.0]
ALL_FIELDS = [0.0, 7.0, 10.0, 14.0, 20.0]


@pytest.mark.parametrize("method", ["fft", "huygens"])
@pytest.mark.parametrize("field_deg", STREHL_FIELDS)
def test_strehl_vs_reference(cooke, ref_data, field_deg, method):
    ref = next(f for f in ref_data["per_field"] if f["field_deg"] == field_deg)["strehl_0p55_fft_pupil128_grid256"]
    _, d = cooke.psf(field_deg, PRIMARY_NM, method, pixel_um=0.25, size=64, pupil_samples=128)
    assert rel(d["strehl"], ref) < 0.02, (d["strehl"], ref)


@pytest.mark.parametrize("field_deg", ALL_FIELDS)
def test_strehl_fft_agrees_with_huygens(cooke, field_deg):
    _, f = cooke.psf(field_deg, PRIMARY_NM, "fft", pixel_um=0.25, size=64, pupil_samples=128)
    _, h = cooke.psf(field_deg, PRIMARY_NM, "huygens", pixel_um=0.25, size=64, pupil_samples=128)
    assert rel(f["strehl"], h["strehl"]) < 0.01, (f["strehl"], h["strehl"])


# ---------------------------------------------------------------- PSF shapes
PIXEL_UM, SIZE = 0.5, 128


def shape_l2(a, b):
    """Relative L2 distance of two PSFs on the same grid, each normalised to unit sum."""
    a, b = a / a.sum(), b / b.sum()
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.fixture(scope="module")
def engine_psfs(cooke):
    out = {}
    for field in (0.0, 20.0):
        for method in ("fft", "huygens"):
            out[field, method] = cooke.psf(field, PRIMARY_NM, method, pixel_um=PIXEL_UM, size=SIZE, pupil_samples=128)
    return out


@pytest.mark.parametrize("field_deg", [0.0, 20.0])
def test_fft_vs_huygens_same_grid(engine_psfs, field_deg):
    fft, _ = engine_psfs[field_deg, "fft"]
    huy, _ = engine_psfs[field_deg, "huygens"]
    assert fft.shape == huy.shape == (SIZE, SIZE)
    assert shape_l2(fft, huy) < 0.03


def _on_reference_grid(psf, diag, x_mm, y_mm):
    """Sample an engine PSF (centred on the chief ray) at the reference's image points."""
    col = (x_mm - diag["chief_x_mm"]) * 1000.0 / PIXEL_UM + SIZE // 2
    row = (y_mm - diag["chief_y_mm"]) * 1000.0 / PIXEL_UM + SIZE // 2
    rr, cc = np.meshgrid(row, col, indexing="ij")
    return map_coordinates(psf, [rr, cc], order=3, mode="constant")


@pytest.mark.parametrize(
    "field_deg, stem",
    [(0.0, "cooke_onaxis_0p55_huygens_N128_img128"), (20.0, "cooke_fullfield20deg_0p55_huygens_N128_img128")],
)
@pytest.mark.parametrize("method", ["fft", "huygens"])
def test_psf_vs_reference_huygens(engine_psfs, ref_dir, field_deg, stem, method):
    ref = np.load(ref_dir / "psf" / f"{stem}.npy")
    x_mm = np.load(ref_dir / "psf" / f"{stem}_x_mm.npy")
    y_mm = np.load(ref_dir / "psf" / f"{stem}_y_mm.npy")
    psf, diag = engine_psfs[field_deg, method]
    ours = _on_reference_grid(psf, diag, x_mm, y_mm)
    assert shape_l2(ours, ref) < 0.03


def test_psf_diagnostics_and_energy(engine_psfs):
    for (field, method), (psf, d) in engine_psfs.items():
        assert np.all(np.isfinite(psf)) and psf.min() >= 0
        assert d["method"] == method and isinstance(d["warnings"], list)
        assert d["transmitted_fraction"] == pytest.approx(1.0, abs=1e-9)  # no apertures
        assert 0.95 < psf.sum() <= 1.0 + 1e-6, (field, method)  # 64 um window holds the PSF
        assert d["energy_in_window"] == pytest.approx(psf.sum(), rel=1e-6)
        # mirror symmetry in x about the chief-ray column SIZE // 2
        assert np.allclose(psf[:, 1:], psf[:, :0:-1], atol=1e-3 * psf.max()), (field, method)
