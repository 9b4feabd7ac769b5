"""Differentiable EMVA 1288 sensor model (Sec. 3.3, Eqs. 3-5).

    I_RAW = b + n_q + K * min(e_SAT, n_d + n_I + sum_lambda p(lambda) eta(lambda))      (Eq. 5)

Per pixel: the linear RGB image becomes a 50-band spectral radiance (spectral.py), Eq. 3 gives
the mean photon count per band, the CFA selects the pixel's QE curve eta_c(lambda), and the
photo-electrons are drawn as ONE Poisson variable with mean sum_lambda mu_p(lambda) eta_c(lambda):
converting photons to electrons with probability eta thins a Poisson(mu_p) into Poisson(mu_p eta),
and a sum of independent Poisson variables is Poisson with the summed mean. Dark current
n_I ~ Poisson(mu_I) (Eq. 4) joins the same draw. Dark noise n_d ~ N(0, sigma_d) (its mean is part
of the black level b). The clip at full well is an exact min (gradient 1 below e_SAT, 0 above),
then gain K, quantisation, black level b and the ADC range [0, 2^bits - 1].
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError
from .cfa import mosaic
from .poisson import poisson_quantile, poisson_sample
from .presets import SensorPreset, check_positive, get_preset
from .spectral import WAVELENGTHS_NM, interpolation_weights, photons_per_radiance

QUANTIZE = ("uniform", "round", "none")


def dark_current_mean(preset, exposure_s: float | None = None, temperature_c: float | None = None) -> float:
    """Eq. 4: mu_I = mu_I.ref * 2^((T - T_ref) / T_d) * t_exp, in electrons."""
    p = get_preset(preset)
    t = p.exposure_s if exposure_s is None else check_positive("exposure_s", exposure_s)
    if temperature_c is not None:
        p = p.with_(temperature_c=float(temperature_c))  # validated: above absolute zero, no overflow
    return p.dark_current_rate_e_per_s * t


def _resolve(preset, exposure_s=None, gain=None, f_number=None, temperature_c=None, cfa=None) -> SensorPreset:
    p = get_preset(preset)
    changes = {
        k: v
        for k, v in dict(
            exposure_s=exposure_s, gain_dn_per_e=gain, f_number=f_number, temperature_c=temperature_c, cfa=cfa
        ).items()
        if v is not None
    }
    if gain is not None:
        check_positive("gain", gain)
    return p.with_(**changes) if changes else p


def _check_image(x: torch.Tensor) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise InputError(f"linear_rgb must be a torch.Tensor, got {type(x).__name__}")
    if x.dim() not in (3, 4) or x.shape[-3] != 3:
        raise InputError(f"linear_rgb must have shape [B, 3, H, W] or [3, H, W], got {tuple(x.shape)}")
    if not x.is_floating_point():
        x = x.float()
    if not bool(torch.isfinite(x).all()):
        raise InputError("linear_rgb contains NaN or infinite values")
    return x


def expected_electrons(linear_rgb: torch.Tensor, preset="imx249", *, exposure_s=None, f_number=None) -> torch.Tensor:
    """Mean photo-electrons [..., 3, H, W] a pixel with the R, G or B filter would collect.

    sum_lambda mu_p(lambda) eta_c(lambda) with mu_p from Eq. 3. Negative input is clipped to 0 by
    the non-negative spectrum. Differentiable.
    """
    p = _resolve(preset, exposure_s=exposure_s, f_number=f_number)
    x = linear_rgb
    interp = interpolation_weights().to(device=x.device, dtype=x.dtype)  # [L, 3]
    # electrons per unit relative spectrum, per channel and band: L_scale * (Eq. 3 factor) * eta
    per_band = (
        p.radiance_scale * photons_per_radiance(p.pixel_um, p.exposure_s, p.f_number) * p.qe_curves(WAVELENGTHS_NM)
    ).to(device=x.device, dtype=x.dtype)  # [3, L]
    spectrum = torch.relu(torch.einsum("lc,...chw->...lhw", interp, x))
    return torch.einsum("cl,...lhw->...chw", per_band, spectrum)


def simulate_raw(
    linear_rgb: torch.Tensor,
    preset="imx249",
    *,
    exposure_s=None,
    gain=None,
    f_number=None,
    temperature_c=None,
    cfa=None,
    noise: bool = True,
    quantize: str = "uniform",
    generator: torch.Generator | None = None,
    common_noise: bool = False,
) -> torch.Tensor:
    """Linear RGB [B, 3, H, W] (or [3, H, W]) -> RAW digital numbers [B, 1, H, W] (or [1, H, W]).

    linear_rgb: relative linear radiance (1.0 = the preset's ``radiance_scale``), >= 0.
    preset: name or SensorPreset; exposure_s, gain (K, DN/e-), f_number, temperature_c (C) and
    cfa override its fields. noise=False returns the mean signal b + K min(e_SAT, mu_e + mu_I)
    (no sampling, no quantisation noise). quantize: "uniform" adds n_q ~ U(-0.5, 0.5) (Eq. 5,
    differentiable), "round" rounds like a real ADC (straight-through gradient), "none" skips it.
    The output has the input's dtype (float32 unless the input is float64) and is differentiable
    w.r.t. linear_rgb (Poisson gradient: see poisson.py). common_noise: see raw_from_electrons.
    """
    p = _resolve(preset, exposure_s, gain, f_number, temperature_c, cfa)
    x = _check_image(linear_rgb)
    squeeze = x.dim() == 3
    if squeeze:
        x = x[None]
    y = raw_from_electrons(
        mosaic(expected_electrons(x, p), p.cfa),
        p,
        noise=noise,
        quantize=quantize,
        generator=generator,
        common_noise=common_noise,
    )
    return y[0] if squeeze else y


def raw_from_electrons(
    photo_electrons: torch.Tensor,
    preset="imx249",
    *,
    noise: bool = True,
    quantize: str = "uniform",
    generator: torch.Generator | None = None,
    common_noise: bool = False,
) -> torch.Tensor:
    """Eq. 5 from the mean photo-electrons per pixel (any shape, e.g. [B, 1, H, W]) to DN, same shape.

    Adds the dark current mu_I (Eq. 4), samples Poisson(mu_e + mu_I) and the dark noise n_d (noise=True),
    clips at full well, applies gain, quantisation (see simulate_raw) and black level, clamps to the ADC.

    common_noise=True (with noise and uniform quantisation; no gradient) draws the same noise
    for any two signals given the same generator state (common random numbers, for paired
    comparisons): the uniform, normal and uniform fields of shot noise, dark noise and
    quantisation are drawn first, in float64 (their number does not depend on the signal), and
    the shot noise is the Poisson quantile of its uniform at the pixel's mean
    (:func:`poisson_quantile`). Sampling ``torch.poisson`` consumes a signal-dependent amount
    of the random stream instead. The fields are drawn on the generator's device (a CPU one:
    the CPU's draws on any device) and the rest runs on the signal's.
    """
    if quantize not in QUANTIZE:
        raise InputError(f"quantize must be one of {', '.join(QUANTIZE)}, got {quantize!r}")
    p = get_preset(preset)
    mu_e = photo_electrons + dark_current_mean(p)
    if common_noise and noise:
        if quantize != "uniform":
            raise InputError("common_noise needs quantize='uniform'")
        with torch.no_grad():
            lam = mu_e.detach().double()
            u_shot, z_read, u_q = (_drawn(d, lam, generator) for d in (torch.rand, torch.randn, torch.rand))
            e = poisson_quantile(u_shot, lam) + p.dark_noise_e * z_read
            y = p.black_level_dn + p.gain_dn_per_e * torch.clamp(e, max=p.full_well_e) + u_q - 0.5
            return y.clamp(0, p.adc_max_dn).to(photo_electrons)
    if noise:
        e = poisson_sample(mu_e, generator=generator)  # photo-electrons + n_I
        e = e + p.dark_noise_e * _drawn(torch.randn, e, generator)  # n_d
    else:
        e = mu_e
    y = p.black_level_dn + p.gain_dn_per_e * torch.clamp(e, max=p.full_well_e)  # Eq. 5 without n_q
    if quantize == "uniform" and noise:
        y = y + _drawn(torch.rand, y, generator) - 0.5
    elif quantize == "round":
        y = y + (torch.round(y) - y).detach()
    return y.clamp(0, p.adc_max_dn)


def _drawn(draw, like: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """``draw`` (torch.rand, torch.randn) of ``like``'s shape and dtype, made on the generator's
    device and moved to ``like``'s: a CPU generator gives the CPU's draws on any device (the
    seeded noise repeats across devices; a CUDA stream would not match the CPU's)."""
    if generator is None:
        return draw(like.shape, dtype=like.dtype, device=like.device)
    return draw(like.shape, generator=generator, dtype=like.dtype, device=generator.device).to(like.device)


def expected_signal(linear_rgb: torch.Tensor, preset="imx249", **overrides) -> torch.Tensor:
    """Noise-free mean RAW signal (simulate_raw with noise=False, quantize='none')."""
    return simulate_raw(linear_rgb, preset, noise=False, quantize="none", **overrides)


def calibrate_radiance_scale(preset="imx249", fraction: float = 0.85) -> float:
    """The radiance_scale giving ``fraction`` of full well in G for a (1, 1, 1) input at the preset's settings."""
    p = get_preset(preset)
    g = expected_electrons(torch.ones(3, 1, 1, dtype=torch.float64), p)[1, 0, 0].item()
    return p.radiance_scale * fraction * p.full_well_e / g


class Sensor(nn.Module):
    """Module twin of :func:`simulate_raw`: [B, 3, H, W] linear RGB -> [B, 1, H, W] RAW DN.

    exposure_s, gain, f_number and temperature_c are plain attributes (None: the preset's value);
    change them between calls, e.g. ``sensor.exposure_s = 1e-3``.
    """

    def __init__(
        self,
        preset="imx249",
        *,
        exposure_s=None,
        gain=None,
        f_number=None,
        temperature_c=None,
        noise: bool = True,
        quantize: str = "uniform",
    ):
        super().__init__()
        self.preset = get_preset(preset)
        self.exposure_s, self.gain, self.f_number, self.temperature_c = exposure_s, gain, f_number, temperature_c
        self.noise, self.quantize = noise, quantize

    def forward(self, x: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return simulate_raw(
            x,
            self.preset,
            exposure_s=self.exposure_s,
            gain=self.gain,
            f_number=self.f_number,
            temperature_c=self.temperature_c,
            noise=self.noise,
            quantize=self.quantize,
            generator=generator,
        )

    def extra_repr(self) -> str:
        return f"preset={self.preset.name}, exposure_s={self.exposure_s}, gain={self.gain}, noise={self.noise}"
