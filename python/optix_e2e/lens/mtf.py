"""Modulation transfer function from the engine's FFT PSFs.

The OTF is the normalized Fourier transform of the PSF.  Along one axis it is the
Fourier transform of the line spread function (projection-slice theorem), so

    OTF_t(f) = sum_y LSF_y(y) exp(-2 pi i f y) / sum LSF_y,   LSF_y = PSF summed over x,

and likewise OTF_s along x.  Fields lie along +y, so the tangential MTF is |OTF| along fy
(lines parallel to x) and the sagittal MTF is |OTF| along fx.  The sum is evaluated
directly at each requested frequency (no FFT grid to interpolate).

The diffraction limit drawn beside it is the closed-form MTF of a perfect circular pupil
with the lens's working f-number N = 1/(2 n' sin u') of the real on-axis marginal ray at
each wavelength (Zemax's "working F/#"; within 0.5% of EFL/EPD for the Cooke triplet).

Sampling (``psf_sampling``): an incoherent PSF is band-limited to the cutoff
f_c = 1/(lambda N).  The PSF is point-sampled (``integrate=False``: no pixel MTF) at
p = lambda_min N / 4, so the grid's Nyquist frequency is twice the highest cutoff; the
window is 90% of the FFT field lambda N P (P pupil samples across), the most the FFT
PSF covers without wrap-around; P starts at 64 and doubles while the geometric spot
(from the chief ray) reaches beyond 85% of the half window or more than 1% of the
energy falls outside.  With P = 64 the window holds 99.8% of a perfect lens's
Airy pattern, and the MTF of a diffraction-limited f/50 lens matches the closed form to
0.3% of unity (tests/lens/test_mtf.py).  Engine warnings (wavefront under-sampled, energy
outside the window) are passed on.

Polychromatic MTF: the wavelengths' complex OTFs, each PSF normalized to unit energy and
weighted by the lens's wavelength weights, are summed with the phase of each
wavelength's chief-ray position, so lateral colour lowers the MTF as it should.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError

__all__ = ["diffraction_mtf", "otf_1d", "psf_sampling", "field_mtf", "NYQUIST_5P86_UM"]

#: Nyquist frequency (cycles/mm) of the 5.86 um pixel of the default sensor.
NYQUIST_5P86_UM = 1e3 / (2 * 5.86)

#: Fraction of the FFT field (lambda N P) that the PSF window spans.
WINDOW_FRACTION = 0.9
#: Largest pupil sampling the window growth goes to (window ~ 460 lambda N).
MAX_PUPIL_SAMPLES = 512


def diffraction_mtf(freq_cyc_mm, wavelength_nm: float, f_number: float) -> np.ndarray:
    """MTF of an aberration-free circular pupil: 2/pi (acos v - v sqrt(1 - v^2)),
    v = f / f_c, f_c = 1 / (lambda N); zero beyond the cutoff."""
    if not (wavelength_nm > 0 and f_number > 0):
        raise InputError(f"diffraction_mtf needs a positive wavelength and f-number, got {wavelength_nm}, {f_number}")
    v = np.clip(np.abs(np.asarray(freq_cyc_mm, dtype=float)) * wavelength_nm * 1e-6 * f_number, 0.0, 1.0)
    return 2.0 / np.pi * (np.arccos(v) - v * np.sqrt(1.0 - v * v))


def otf_1d(
    psf: np.ndarray, pixel_um: float, freq_cyc_mm, axis: str, offset_mm: float = 0.0, total: float | None = None
) -> np.ndarray:
    """Complex OTF along ``axis`` ("x": sagittal, "y": tangential) of a PSF whose pixel
    (size//2, size//2) lies at ``offset_mm`` along that axis.

    ``total``: the PSF's whole energy (the engine's transmitted fraction) when part of it
    lies outside the window.  That part is a faint, smooth halo whose transform is
    confined below ~1/window, so it counts at f = 0 only: OTF(0) = 1 and
    OTF(f > 0) = transform of the window / total (this halves the error of a truncated
    Airy pattern's MTF at low frequencies).  Default: the window's sum.
    """
    if axis not in ("x", "y"):
        raise InputError(f"axis must be 'x' or 'y', got {axis!r}")
    lsf = psf.sum(axis=1 if axis == "y" else 0)  # rows are y
    inside = float(lsf.sum())
    if not inside > 0:
        raise InputError("the PSF holds no energy: no OTF")
    total = inside if total is None else max(float(total), inside)
    coord = (np.arange(lsf.size) - lsf.size // 2) * pixel_um * 1e-3 + offset_mm
    f = np.atleast_1d(np.asarray(freq_cyc_mm, dtype=float))
    otf = np.exp(-2j * np.pi * np.outer(f, coord)) @ lsf / total
    return np.where(f == 0.0, 1.0 + 0.0j, otf)


def working_f_number(lens, wavelength_nm: float, aiming: str = "paraxial") -> float:
    """Image-space working f-number 1 / (2 n' sin u') of the real on-axis marginal ray
    (what the diffraction cutoff depends on); the paraxial EFL/EPD where that ray fails."""
    t = lens.trace_field(0.0, np.zeros(2), np.array([1.0, -1.0]), wavelength_nm, aiming=aiming)
    if np.any(t["status"] != 0):
        return float(lens.paraxial(wavelength_nm)["f_number"])
    n_img = float(lens.refractive_indices(wavelength_nm)[-1])
    sin_u = float(np.mean(np.hypot(t["direction"][:, 0], t["direction"][:, 1])))
    return 1.0 / (2.0 * n_img * sin_u)


def psf_sampling(lens, wavelengths_nm: Sequence[float], pupil_samples: int = 64) -> dict[str, float]:
    """Pixel pitch and window for MTF-grade PSFs (see the module docstring)."""
    if pupil_samples < 16:
        raise InputError(f"pupil_samples must be at least 16 for an MTF, got {pupil_samples}")
    n_f = min(working_f_number(lens, w) for w in wavelengths_nm)
    lam_min_um = min(wavelengths_nm) * 1e-3
    pixel_um = lam_min_um * n_f / 4.0
    size = int(WINDOW_FRACTION * 4 * pupil_samples) // 2 * 2
    return {
        "pixel_um": pixel_um,
        "size": size,
        "pupil_samples": pupil_samples,
        "f_number": n_f,
        "window_um": pixel_um * size,
        "grid_nyquist_cyc_mm": 1e3 / (2 * pixel_um),
    }


def _sized_psf(lens, field_deg: float, wl: float, samp: dict, aiming: str, method: str = "fft"):
    """FFT PSF at the MTF sampling, its window (and pupil sampling, which bounds the
    window) grown by powers of two until the geometric spot extent, measured from the
    chief ray, stays inside 85% of the half window (FFT: the engine reports the extent)
    and the window holds 99% of the transmitted energy; at most MAX_PUPIL_SAMPLES.
    Huygens PSFs keep the first window (see below); an FFT PSF the engine refuses is
    replaced by the Huygens PSF at that sampling (its record says "method": "huygens")."""
    from .. import engine

    p_um, n_pupil = samp["pixel_um"], samp["pupil_samples"]
    while True:
        size = int(WINDOW_FRACTION * 4 * n_pupil) // 2 * 2
        try:
            psf, d = lens.psf(
                field_deg, wl, method, pixel_um=p_um, size=size, pupil_samples=n_pupil, aiming=aiming, integrate=False
            )
        except engine.PsfError as err:
            if method != "fft":
                raise
            # The engine refuses an FFT PSF that fails its own checks (an exit pupil too
            # distorted for one FFT over the window): the Huygens PSF, the reference, instead,
            # at the first window (as a Huygens request keeps it, see below).
            method, n_pupil = "huygens", samp["pupil_samples"]
            size = int(WINDOW_FRACTION * 4 * n_pupil) // 2 * 2
            psf, d = lens.psf(
                field_deg, wl, method, pixel_um=p_um, size=size, pupil_samples=n_pupil, aiming=aiming, integrate=False
            )
            d = {
                **d,
                "warnings": [f"FFT PSF refused ({str(err).split(' (')[0]}); Huygens PSF used", *d.get("warnings", [])],
            }
        extent = max(float(d.get("spot_extent_x_um", 0.0)), float(d.get("spot_extent_y_um", 0.0)))
        need = extent / (0.85 * 0.5 * size * p_um)
        # Diffraction spreads light past the rays: also grow while the window holds
        # less than 99% of the transmitted energy (a perfect lens's Airy pattern: 99.9%).
        if float(d.get("energy_in_window", 1.0)) < 0.99 * float(d.get("transmitted_fraction", 1.0)):
            need = max(need, 2.0)
        # Huygens: a larger window leaves the engine's fast separable evaluation (100x
        # slower), so its window stays fixed; the engine warns when energy falls outside.
        if method == "huygens":
            need = 0.0
        if need <= 1.0 or n_pupil >= MAX_PUPIL_SAMPLES:
            return (
                psf,
                d,
                {
                    "pupil_samples": n_pupil,
                    "size": size,
                    "window_um": size * p_um,
                    "spot_extent_um": extent,
                    "method": method,
                },
            )
        n_pupil = min(MAX_PUPIL_SAMPLES, n_pupil * 2 ** math.ceil(math.log2(need)))


def default_frequencies(wavelengths_nm: Sequence[float], f_number: float, n: int = 101) -> np.ndarray:
    """0 .. the diffraction cutoff of the shortest wavelength, ``n`` points."""
    return np.linspace(0.0, 1.0 / (min(wavelengths_nm) * 1e-6 * f_number), n)


def field_mtf(
    lens,
    field_deg: float,
    freq_cyc_mm=None,
    wavelengths_nm: Sequence[float] | None = None,
    weights: Sequence[float] | None = None,
    aiming: str = "paraxial",
    pupil_samples: int = 64,
    method: str = "fft",
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """Tangential and sagittal MTF of one field, polychromatic and per wavelength, from
    FFT PSFs (``method="huygens"``: Huygens PSFs, the reference where the FFT's
    assumptions break, e.g. strongly distorted exit pupils at large fields).

    Returns freq_cyc_mm, tangential, sagittal (polychromatic), per_wavelength
    ({"wavelength_nm", "tangential", "sagittal", "diffraction_limit"} each),
    diffraction_limit (weighted over the wavelengths, same f-number), cutoff_cyc_mm (of
    the shortest wavelength), f_number (working, on axis), sampling, warnings (engine warnings, prefixed by the
    wavelength) and strehl per wavelength (None where the engine does not trust it).
    """
    if method not in ("fft", "huygens"):
        raise InputError(f"MTF PSF method must be 'fft' or 'huygens', got {method!r}")
    if wavelengths_nm is None:
        wavelengths_nm = lens.wavelengths_nm
        weights = lens.wavelength_weights if weights is None else weights
    wavelengths_nm = [float(w) for w in wavelengths_nm]
    weights = [1.0] * len(wavelengths_nm) if weights is None else [float(w) for w in weights]
    if not wavelengths_nm or len(weights) != len(wavelengths_nm):
        raise InputError(f"{len(wavelengths_nm)} wavelengths and {len(weights)} weights")
    if any(w < 0 for w in weights) or sum(weights) <= 0:
        raise InputError(f"wavelength weights must be >= 0 with a positive sum, got {weights}")
    samp = psf_sampling(lens, wavelengths_nm, pupil_samples)
    freq = (
        default_frequencies(wavelengths_nm, samp["f_number"]) if freq_cyc_mm is None else np.asarray(freq_cyc_mm, float)
    )
    if freq.ndim != 1 or np.any(~np.isfinite(freq)) or np.any(freq < 0):
        raise InputError("frequencies must be a 1-D list of finite values >= 0 (cycles/mm)")
    too_high = freq[freq > samp["grid_nyquist_cyc_mm"]]
    if too_high.size:
        raise InputError(
            f"{too_high.max():g} cycles/mm is beyond the PSF grid's Nyquist frequency "
            f"{samp['grid_nyquist_cyc_mm']:.1f} (twice the diffraction cutoff)"
        )
    wsum = sum(weights)
    n_w = {wl: working_f_number(lens, wl, aiming) for wl in wavelengths_nm}
    otf_t = np.zeros(freq.size, complex)
    otf_s = np.zeros(freq.size, complex)
    per_wl, warnings, strehl, sampling_used = [], [], [], []
    for wl, w in zip(wavelengths_nm, weights):
        if progress:
            progress(f"PSF {field_deg:g} deg, {wl:g} nm")
        psf, d, used = _sized_psf(lens, field_deg, wl, samp, aiming, method)
        sampling_used.append(used)
        warnings += [f"{field_deg:g} deg, {wl:g} nm: {m}" for m in d.get("warnings", [])]
        strehl.append(d.get("strehl"))
        # Chief-ray position (mm) puts each wavelength's OTF on a common origin.
        total = float(d.get("transmitted_fraction", 0.0))
        ot = otf_1d(psf, samp["pixel_um"], freq, "y", float(d.get("chief_y_mm", 0.0)), total)
        os_ = otf_1d(psf, samp["pixel_um"], freq, "x", float(d.get("chief_x_mm", 0.0)), total)
        otf_t += w / wsum * ot
        otf_s += w / wsum * os_
        per_wl.append(
            {
                "wavelength_nm": wl,
                "weight": w,
                "tangential": np.abs(ot),
                "sagittal": np.abs(os_),
                "f_number": n_w[wl],
                "diffraction_limit": diffraction_mtf(freq, wl, n_w[wl]),
            }
        )
    dl = sum(p["weight"] / wsum * p["diffraction_limit"] for p in per_wl)
    return {
        "field_deg": float(field_deg),
        "freq_cyc_mm": freq,
        "tangential": np.abs(otf_t),
        "sagittal": np.abs(otf_s),
        "diffraction_limit": dl,
        "per_wavelength": per_wl,
        "cutoff_cyc_mm": max(1.0 / (wl * 1e-6 * n) for wl, n in n_w.items()),
        "method": method,
        "sampling": samp,
        "sampling_per_wavelength": sampling_used,
        "aiming": aiming,
        "strehl": strehl,
        "warnings": warnings,
    }


def mtf_at(result: dict[str, Any], freq_cyc_mm: float) -> dict[str, float]:
    """Tangential, sagittal and diffraction-limited MTF at one frequency (linear
    interpolation on the result's frequency grid)."""
    f = result["freq_cyc_mm"]
    if not (f[0] <= freq_cyc_mm <= f[-1]):
        raise InputError(f"{freq_cyc_mm:g} cycles/mm is outside the computed range {f[0]:g}..{f[-1]:g}")
    return {k: float(np.interp(freq_cyc_mm, f, result[k])) for k in ("tangential", "sagittal", "diffraction_limit")}
