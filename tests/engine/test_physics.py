"""Engine results against textbook optics, through the bindings.

A slow plano-convex singlet (f = 100 mm, f/50) is diffraction limited: its PSF is the Airy
pattern.  Moving its image plane gives pure defocus (Strehl = sinc^2 and Marechal), and
a faster copy checks third-order spherical aberration against a Seidel sum computed here
with an independent numpy paraxial trace.
"""

import numpy as np
import pytest

from optix_e2e.lens import Lens

N_GLASS, R1, D = 1.5, 50.0, 5.0  # plano-convex, f = R1/(n-1) = 100 mm
WL_NM = 550.0


def paraxial_trace(surfaces, h0):
    """y-nu trace of a marginal ray from infinity; returns per-surface (h, u, u', n, n', c)
    and the final (h, u') after the last surface (before the last gap)."""
    h, u, n = h0, 0.0, 1.0
    rows = []
    for c, t, n2 in surfaces:
        u2 = (n * u - h * c * (n2 - n)) / n2
        rows.append((h, u, u2, n, n2, c))
        h, u, n = h + t * u2, u2, n2
    return rows


def plano_convex(epd, curved_first=True, image_shift=0.0):
    """Returns (Lens, back focal length) with the image plane at paraxial focus + shift."""
    c_a, c_b = (1.0 / R1, 0.0) if curved_first else (0.0, -1.0 / R1)
    rows = paraxial_trace([(c_a, D, N_GLASS), (c_b, 0.0, 1.0)], 1.0)
    h_last, u_last = rows[-1][0], rows[-1][2]
    bfl = -h_last / u_last
    radius = lambda c: "inf" if c == 0 else 1.0 / c
    lens = Lens(
        {
            "name": "plano-convex",
            "aperture": {"type": "epd", "value": epd},
            "fields_deg": [0.0],
            "wavelengths_nm": [WL_NM],
            "surfaces": [
                {"radius": radius(c_a), "thickness": D, "material": {"n": N_GLASS}, "stop": True},
                {"radius": radius(c_b), "thickness": bfl + image_shift, "material": "air"},
            ],
        }
    )
    return lens, bfl


def test_numpy_paraxial_agrees_with_engine():
    lens, bfl = plano_convex(2.0)
    par = lens.paraxial()
    assert par["efl_mm"] == pytest.approx(R1 / (N_GLASS - 1), rel=1e-12)
    assert par["bfl_mm"] == pytest.approx(bfl, rel=1e-12)
    assert abs(par["back_focus_shift_mm"]) < 1e-9


def _first_zero_um(row, pixel_um, guess_um):
    """First minimum of a PSF cut (centre at len//2) near guess, parabola-refined, both sides averaged."""
    c = len(row) // 2
    radii = []
    for side in (1, -1):
        lo, hi = int(0.8 * guess_um / pixel_um), int(1.2 * guess_um / pixel_um)
        idx = np.arange(lo, hi + 1)
        vals = row[c + side * idx]
        k = int(np.argmin(vals))
        assert 0 < k < len(idx) - 1, "no minimum inside the search range"
        y0, y1, y2 = vals[k - 1], vals[k], vals[k + 1]
        radii.append((idx[k] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)) * pixel_um)
    return float(np.mean(radii))


@pytest.mark.parametrize("method", ["fft", "huygens"])
def test_perfect_lens_gives_airy_pattern(method):
    lens, _ = plano_convex(2.0)  # f/50
    f_number = lens.paraxial()["f_number"]
    expected = 1.22 * WL_NM * 1e-3 * f_number  # um
    pixel = 0.5
    psf, d = lens.psf(0.0, WL_NM, method, pixel_um=pixel, size=192, pupil_samples=64)
    assert d["strehl"] == pytest.approx(1.0, abs=0.01)
    c = psf.shape[0] // 2
    assert _first_zero_um(psf[c, :], pixel, expected) == pytest.approx(expected, rel=0.01)
    assert _first_zero_um(psf[:, c], pixel, expected) == pytest.approx(expected, rel=0.01)
    assert psf[c, c] == psf.max()


def test_psf_energy_is_conserved():
    lens, _ = plano_convex(2.0)
    psf, d = lens.psf(0.0, WL_NM, "fft", pixel_um=2.0, size=256, pupil_samples=64)
    # Airy encircled energy within a 256 um half-width is ~98%; nothing is created
    assert 0.97 < psf.sum() <= 1.0 + 1e-6
    assert d["transmitted_fraction"] == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("w020_waves", [0.1, 0.15])
def test_defocus_strehl_follows_marechal(w020_waves):
    lens0, _ = plano_convex(2.0)
    f_number = lens0.paraxial()["f_number"]
    dz = w020_waves * WL_NM * 1e-6 * 8 * f_number**2  # W020 = dz / (8 N^2)
    lens, _ = plano_convex(2.0, image_shift=dz)
    _, d = lens.psf(0.0, WL_NM, "fft", pixel_um=0.5, size=128, pupil_samples=64)
    exact = np.sinc(w020_waves) ** 2  # uniform pupil, pure defocus
    sigma = w020_waves / np.sqrt(12.0)  # rms of W020 rho^2, piston removed
    marechal = np.exp(-((2 * np.pi * sigma) ** 2))
    assert d["strehl"] == pytest.approx(exact, rel=0.01)
    assert d["strehl"] == pytest.approx(marechal, rel=0.02)


@pytest.mark.parametrize("curved_first", [True, False])
def test_third_order_spherical_aberration(curved_first):
    """Transverse ray aberration at the paraxial focus vs the Seidel sum (small aperture)."""
    epd = 4.0  # f/25: fifth-order terms are well below 1% of the third-order one
    h = epd / 2
    lens, bfl = plano_convex(epd, curved_first)
    c_a, c_b = (1.0 / R1, 0.0) if curved_first else (0.0, -1.0 / R1)
    rows = paraxial_trace([(c_a, D, N_GLASS), (c_b, 0.0, 1.0)], h)
    s1 = -sum((n * (hh * c + u)) ** 2 * hh * (u2 / n2 - u / n) for hh, u, u2, n, n2, c in rows)
    u_image = rows[-1][2]
    theory = abs(s1 / 2.0 / u_image)  # |transverse SA| = |4 W040 / (n' u')|, W040 = S_I / 8

    origins = np.array([[0.0, h, -1.0], [0.0, 0.5 * h, -1.0]])
    directions = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    from optix_e2e import _engine

    out = _engine.trace(lens.to_engine_json(), origins, directions, WL_NM)
    assert np.all(out["status"] == 0)
    y_edge, y_half = out["position"][:, 1]
    assert y_edge < 0  # undercorrected positive lens: the marginal ray crosses the axis early
    assert abs(y_edge) == pytest.approx(theory, rel=0.02)
    assert y_half / y_edge == pytest.approx(0.125, rel=0.02)  # cubic in pupil height
    if curved_first:  # the well-known shape dependence: flat side first is ~4x worse
        other, _ = plano_convex(epd, False)
        y_flat_first = _engine.trace(other.to_engine_json(), origins, directions, WL_NM)["position"][0, 1]
        assert abs(y_flat_first) > 3 * abs(y_edge)


@pytest.mark.parametrize("field_deg", [0.0, 14.9])
def test_fft_and_huygens_agree_on_a_strongly_aberrated_pupil(field_deg):
    """The paper triplet at 550 nm (Strehl 0.016 on axis): two independent evaluations of
    the diffraction integral over the reference sphere, both converged in sampling, agree
    to 0.2% relative L1. The FFT integrates over the directions from each sphere point to
    the sphere's centre; with the rays' own directions instead (the transverse aberration
    over R off) they differed by 2.2% here."""
    lens = Lens.load("paper-triplet")
    kw = dict(pixel_um=1.0, size=128, pupil_samples=256)
    huy, _ = lens.psf(field_deg, WL_NM, "huygens", **kw)
    fft, d = lens.psf(field_deg, WL_NM, "fft", fft_grid=2048, **kw)
    assert d["warnings"] == []
    assert np.abs(fft - huy).sum() / huy.sum() < 2e-3
