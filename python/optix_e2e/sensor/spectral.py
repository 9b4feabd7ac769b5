"""RGB -> 50-band spectrum and the mean photon count per band (Sec. 3.3, Eq. 3).

Spectral model. The paper extends the RGB image to 50 bands "using quadratic interpolation
between the RGB color channels". We place B, G and R at representative wavelengths (about the
dominant wavelengths of the sRGB primaries: 465, 550, 610 nm), evaluate the quadratic through
those three points (Lagrange form) inside [465, 610] nm, hold the end values outside it (no
runaway extrapolation to 400 / 700 nm), and clamp the result at >= 0. The map is linear in RGB
before the clamp and the Lagrange weights sum to 1, so grey (v, v, v) gives the flat spectrum v.
Bands: 50 bins of 6 nm tiling 400-700 nm, centres 403, 409, ..., 697 nm.

Units. ``rgb_to_spectrum`` returns relative values; a preset's ``radiance_scale`` turns them into
spectral radiance L (W m^-2 sr^-1 nm^-1). ``photon_count_mean`` implements Eq. 3.
"""

from __future__ import annotations

import math

import torch
from torch import nn

H_PLANCK = 6.62607015e-34  # J s (the paper rounds to 6.626e-34)
C_LIGHT = 299_792_458.0  # m / s
N_BANDS = 50
BAND_NM = 6.0
WAVELENGTHS_NM = tuple(400.0 + BAND_NM * (i + 0.5) for i in range(N_BANDS))
ANCHORS_NM = (610.0, 550.0, 465.0)  # where the R, G, B values sit on the wavelength axis


def interpolation_weights(wavelengths_nm=WAVELENGTHS_NM, anchors_nm=ANCHORS_NM) -> torch.Tensor:
    """[L, 3] weights w so that spectrum(lambda) = sum_c w[lambda, c] * rgb[c] (before the >= 0 clamp)."""
    lam = torch.as_tensor(wavelengths_nm, dtype=torch.float64)
    a = torch.as_tensor(anchors_nm, dtype=torch.float64)
    lam = lam.clamp(float(a.min()), float(a.max()))  # hold the end values outside the anchors
    cols = []
    for j in range(3):  # Lagrange basis polynomial of anchor j
        col = torch.ones_like(lam)
        for m in range(3):
            if m != j:
                col = col * (lam - a[m]) / (a[j] - a[m])
        cols.append(col)
    return torch.stack(cols, dim=-1)


def rgb_to_spectrum(rgb: torch.Tensor) -> torch.Tensor:
    """Linear RGB [..., 3, H, W] -> relative spectrum [..., 50, H, W] (quadratic interpolation, >= 0)."""
    w = interpolation_weights().to(device=rgb.device, dtype=rgb.dtype)
    return torch.relu(torch.einsum("lc,...chw->...lhw", w, rgb))


class RGBToSpectrum(nn.Module):
    """Module twin of :func:`rgb_to_spectrum` ([..., 3, H, W] -> [..., 50, H, W])."""

    def __init__(self):
        super().__init__()
        self.register_buffer("weights", interpolation_weights().float())
        self.register_buffer("wavelengths_nm", torch.tensor(WAVELENGTHS_NM))

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return torch.relu(torch.einsum("lc,...chw->...lhw", self.weights.to(rgb.dtype), rgb))


def photons_per_radiance(
    pixel_um: float, exposure_s: float, f_number: float, wavelengths_nm=WAVELENGTHS_NM, band_nm: float = BAND_NM
) -> torch.Tensor:
    """[L] mean photons per pixel per band for a spectral radiance of 1 W m^-2 sr^-1 nm^-1.

    Eq. 3: mu_p = I_MS * pi A t lambda^2 / (h c (1 + (2N)^2)).  Read dimensionally, one factor
    lambda is the photon energy hc/lambda and the other is the band width the spectral radiance is
    integrated over, so we use lambda * delta_lambda:
        irradiance on the pixel  E = pi * L * delta_lambda / (1 + (2N)^2)      [W m^-2]
        photons                  mu_p = E * A * t / (h c / lambda)
    with L in W m^-2 sr^-1 nm^-1, delta_lambda in nm, lambda in m, A in m^2, t in s.  This is the
    EMVA 1288 photon count mu_p = A E t lambda / (h c) for an image-space f-number N.
    """
    lam_m = torch.as_tensor(wavelengths_nm, dtype=torch.float64) * 1e-9
    area_m2 = (pixel_um * 1e-6) ** 2
    etendue = math.pi * area_m2 * exposure_s * band_nm * aperture_factor(f_number)
    return etendue * lam_m / (H_PLANCK * C_LIGHT)


def aperture_factor(f_number):
    """Eq. 3's f-number term 1 / (1 + (2N)^2) (a float, or a tensor and differentiable in N).

    This is Eq. 3's own form, the solid angle of the image-side cone of half-angle
    arctan(1 / 2N), not the small-angle 1 / (4 N^2): f/3.2 collects 78.44 / 41.96 = 1.869 x
    the photons of f/4.4, not (4.4 / 3.2)^2 = 1.891 x."""
    return 1.0 / (1.0 + (2.0 * f_number) ** 2)


def aperture_gain(f_number, reference_f_number: float):
    """Photons at ``f_number`` over photons at ``reference_f_number`` for the same scene (Eq. 3)."""
    return aperture_factor(f_number) / aperture_factor(float(reference_f_number))


def photon_count_mean(radiance: torch.Tensor, pixel_um: float, exposure_s: float, f_number: float) -> torch.Tensor:
    """Eq. 3 per band: spectral radiance [..., 50, H, W] (W m^-2 sr^-1 nm^-1) -> mean photons [..., 50, H, W]."""
    k = photons_per_radiance(pixel_um, exposure_s, f_number).to(device=radiance.device, dtype=radiance.dtype)
    return radiance * k[:, None, None]
