"""MTF from the engine's FFT PSFs (optix_e2e.lens.mtf) against closed forms and another tool.

* A Gaussian PSF's OTF is exp(-2 pi^2 sigma^2 f^2), with the phase of its offset.
* A diffraction-limited lens (the slow plano-convex singlet of test_physics.py) has the
  MTF 2/pi (acos v - v sqrt(1 - v^2)), v = f lambda N: within 0.5% of unity at every
  frequency (measured: 0.27%).
* The Cooke triplet on axis at 550 nm matches the MTF of optiland's own FFT PSF
  (../shared/reference/psf, 128 pupil samples) within 0.005 (measured 0.0029), and at
  every field and wavelength it lies below the diffraction limit (within the method's
  0.003 error; measured excess at most 0.0006).
"""

import json

import numpy as np
import pytest
from test_physics import WL_NM, plano_convex

from optix_e2e.lens.mtf import NYQUIST_5P86_UM, diffraction_mtf, field_mtf, otf_1d


def test_diffraction_mtf_closed_form_points():
    n, wl = 5.0, 550.0
    fc = 1.0 / (wl * 1e-6 * n)
    m = diffraction_mtf([0.0, 0.5 * fc, fc, 1.5 * fc], wl, n)
    # v = 1/2: 2/pi (pi/3 - sqrt(3)/4) = 0.39100
    assert m == pytest.approx([1.0, 2 / np.pi * (np.pi / 3 - np.sqrt(3) / 4), 0.0, 0.0], abs=1e-12)
    with pytest.raises(ValueError):
        diffraction_mtf([1.0], 550.0, 0.0)


def test_otf_of_a_gaussian_psf():
    sigma_um, pixel_um, shift_um = 3.0, 0.5, 1.5
    c = np.arange(256) - 128
    x = c * pixel_um
    g = np.exp(-((x - shift_um) ** 2) / (2 * sigma_um**2))
    psf = np.outer(np.exp(-(x**2) / (2 * (2 * sigma_um) ** 2)), g)  # rows y (sigma 6), cols x (sigma 3)
    f = np.linspace(0, 200, 41)
    s = otf_1d(psf, pixel_um, f, "x", offset_mm=0.01)
    t = otf_1d(psf, pixel_um, f, "y")
    expect_s = np.exp(-2 * np.pi**2 * (sigma_um * 1e-3) ** 2 * f**2) * np.exp(
        -2j * np.pi * f * (0.01 + shift_um * 1e-3)
    )
    assert np.abs(s - expect_s).max() < 1e-9
    assert np.abs(t - np.exp(-2 * np.pi**2 * (2 * sigma_um * 1e-3) ** 2 * f**2)).max() < 1e-9
    with pytest.raises(ValueError, match="axis"):
        otf_1d(psf, pixel_um, f, "z")
    with pytest.raises(ValueError, match="no energy"):
        otf_1d(np.zeros((8, 8)), pixel_um, f, "x")


@pytest.mark.parametrize("epd", [2.0, 5.0])  # f/50 and f/20: Strehl 1.000 and 0.998
def test_diffraction_limited_lens_mtf_matches_closed_form(epd):
    lens, _ = plano_convex(epd)
    n_par = lens.paraxial()["f_number"]
    r = field_mtf(lens, 0.0)
    f = r["freq_cyc_mm"]
    assert f[-1] == pytest.approx(1.0 / (WL_NM * 1e-6 * n_par), rel=2e-3)  # cutoff, working N ~ paraxial N
    expect = diffraction_mtf(f, WL_NM, n_par)
    assert r["tangential"][0] == r["sagittal"][0] == 1.0
    for k in ("tangential", "sagittal"):
        err = np.abs(r[k] - expect)
        assert err.max() < 0.005, f"{k}: max |MTF - closed form| {err.max():.4f} at {f[np.argmax(err)]:.1f} cycles/mm"
    assert np.abs(r["diffraction_limit"] - expect).max() < 0.002  # working vs paraxial f-number
    assert r["warnings"] == []


def test_cooke_on_axis_matches_optiland_psf(cooke, ref_dir):
    # optiland's FFT PSF (128 pupil samples on a 256 grid) is periodic over its window:
    # its Fourier coefficients at the harmonics m / window are its OTF.
    name = "cooke_onaxis_0p55_fft_N128_grid256.npy"
    meta = json.loads((ref_dir / "psf" / "psf_meta.json").read_text())[name]
    ref = np.load(ref_dir / "psf" / name)
    pixel = meta["pixel_pitch_um"]
    f = np.arange(0, 126) / (ref.shape[0] * pixel * 1e-3)  # up to ~360 cycles/mm (cutoff 365)
    r = field_mtf(cooke, 0.0, f, wavelengths_nm=[550.0])
    for k, axis in (("tangential", "y"), ("sagittal", "x")):
        ours, theirs = r[k], np.abs(otf_1d(ref, pixel, f, axis))
        assert np.abs(ours - theirs).max() < 0.005, np.abs(ours - theirs).max()
    # At the Nyquist frequency of a 5.86 um pixel both give ~0.155.
    assert np.interp(NYQUIST_5P86_UM, f, r["tangential"]) == pytest.approx(
        np.interp(NYQUIST_5P86_UM, f, np.abs(otf_1d(ref, pixel, f, "y"))), abs=0.005
    )


def test_cooke_mtf_lies_below_the_diffraction_limit(cooke):
    for field in cooke.fields_deg:
        r = field_mtf(cooke, field)
        assert r["warnings"] == []
        curves = [(r["tangential"], r["sagittal"], r["diffraction_limit"])]
        curves += [(p["tangential"], p["sagittal"], p["diffraction_limit"]) for p in r["per_wavelength"]]
        for t, s, dl in curves:
            assert np.all(t <= dl + 0.003) and np.all(s <= dl + 0.003), field
            assert np.all((t >= 0) & (t <= 1 + 1e-12))
        # Real aberrations: well below the limit at mid frequencies.
        mid = np.argmin(np.abs(r["freq_cyc_mm"] - 100.0))
        assert r["tangential"][mid] < 0.8 * r["diffraction_limit"][mid]


@pytest.mark.parametrize("field", [14.0, 20.0])
def test_off_axis_fft_mtf_matches_huygens(cooke, field):
    # Off axis the exit pupil is anamorphic and distorted: the FFT PSF's corrections
    # against the direct Huygens sum, through the MTF (measured: within 0.0053).
    f = np.linspace(0.0, 360.0, 73)
    fft = field_mtf(cooke, field, f, wavelengths_nm=[550.0])
    huy = field_mtf(cooke, field, f, wavelengths_nm=[550.0], method="huygens")
    for k in ("tangential", "sagittal"):
        assert np.abs(fft[k] - huy[k]).max() < 0.01, (k, np.abs(fft[k] - huy[k]).max())
    assert fft["tangential"][17] < 0.5 * fft["sagittal"][17] if field == 14.0 else True  # astigmatism at 85 c/mm


def test_mtf_rejects_bad_requests(cooke):
    with pytest.raises(ValueError, match="Nyquist"):
        field_mtf(cooke, 0.0, [10.0, 5000.0])
    with pytest.raises(ValueError, match="frequencies"):
        field_mtf(cooke, 0.0, [-1.0, 10.0])
    with pytest.raises(ValueError, match="weights"):
        field_mtf(cooke, 0.0, [10.0], wavelengths_nm=[550.0, 650.0], weights=[1.0])
    with pytest.raises(ValueError, match="method"):
        field_mtf(cooke, 0.0, [10.0], method="geometric")
    with pytest.raises(ValueError, match="pupil_samples"):
        field_mtf(cooke, 0.0, [10.0], pupil_samples=8)


def test_a_refused_fft_psf_falls_back_to_huygens():
    # an end-to-end design whose exit pupil at the full field is too distorted for the FFT:
    # the engine refuses that PSF (at the grown window, 256 pupil samples), and the MTF (and the design run's lens report) uses the
    # Huygens PSF there instead of failing; the other wavelengths keep the FFT
    from pathlib import Path

    from optix_e2e.lens import Lens

    lens = Lens.load(Path(__file__).parents[1] / "data" / "distorted_pupil_triplet.json")
    m = field_mtf(lens, 14.9)
    used = {p["wavelength_nm"]: s["method"] for p, s in zip(m["per_wavelength"], m["sampling_per_wavelength"])}
    assert used[470.0] == "huygens" and "fft" in used.values()
    assert any("FFT PSF refused" in w for w in m["warnings"])
    ref = field_mtf(lens, 14.9, wavelengths_nm=[470.0], method="huygens")
    np.testing.assert_allclose(m["per_wavelength"][0]["tangential"], ref["per_wavelength"][0]["tangential"], atol=1e-12)
    assert (
        np.all(np.isfinite(m["tangential"]))
        and 0.0 <= m["tangential"].min()
        and m["tangential"][0] == pytest.approx(1.0)
    )
