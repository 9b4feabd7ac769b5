"""Photon-transfer analysis (EMVA 1288) of the simulated sensor.

Flat fields of white light on a patch of the sensor, at ``n_levels`` equally spaced irradiances
from dark to ``max_fraction`` x saturation, two frames per level, real rounding in the ADC. The
analysis uses the green pixels of the CFA:
    mu_y        mean of the two frames, minus the dark mean mu_y.dark
    sigma_y^2   var(y_A - y_B) / 2 (temporal variance, free of fixed pattern)
    K           slope of sigma_y^2 - sigma_y.dark^2 against mu_y - mu_y.dark, least squares through the
                origin over 0-70% of saturation (photon transfer: sigma_y^2 = K^2 sigma_d^2 + 1/12 + K mu_y)
    sigma_d     sqrt(sigma_y.dark^2 - 1/12) / K (e-)
    mu_e.sat    (mu_y - mu_y.dark at the maximum of the variance) / K
    LE          linearity error: (max - min)/2 of the % deviation of mu_y - mu_y.dark from a straight
                line against the mean photo-electrons (the exposure axis), over 5-95% of saturation.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..io import save_figure, write_record_atomic
from .cfa import bayer_masks
from .emva import _resolve, dark_current_mean, expected_electrons, raw_from_electrons

COMPARED = {
    "gain": "measured K vs the preset's gain_dn_per_e",
    "dark_noise": "measured temporal dark noise vs sqrt(sigma_d^2 + mu_I) (read noise plus dark-current "
    "shot noise at this exposure and temperature: what a dark frame pair measures)",
    "saturation": "EMVA saturation capacity (mean at the variance peak, in e-) vs the preset's saturation: "
    "full well, or (ADC max - black level)/K where the ADC clips first. The variance peaks a "
    "little before hard clipping, so the measured value sits slightly below it",
}


MIN_SPAN_DN = 10.0  # dark to saturation: fewer DN leave quantisation steps, not a curve
MIN_SATURATION_E = 10.0  # fewer electrons at saturation leave no shot-noise curve to fit


def check_measurable(p, e_per_unit: float, max_fraction: float = 1.15) -> None:
    """A one-line ValueError when the sensor settings leave nothing a photon-transfer series can
    measure: dark frames already saturated, saturation below a few electrons or a few DN, or an
    input level beyond float32 needed to reach saturation."""
    mu_dark = dark_current_mean(p)
    sat = p.saturation_e
    settings = f"exposure {p.exposure_s:g} s, gain K {p.gain_dn_per_e:g} DN/e-, {p.temperature_c:g} C"
    if mu_dark + 3.0 * math.sqrt(mu_dark + p.dark_noise_e**2) >= sat:
        raise InputError(
            f"photon transfer: dark frames saturate ({mu_dark:.4g} e- of dark current against a "
            f"saturation of {sat:.4g} e-; {settings})"
        )
    if sat < MIN_SATURATION_E:
        raise InputError(
            f"photon transfer: saturation at {sat:.3g} e- (ADC range / gain K) is below "
            f"{MIN_SATURATION_E:g} e-: no shot-noise curve to measure ({settings})"
        )
    if p.gain_dn_per_e * sat < MIN_SPAN_DN:
        raise InputError(
            f"photon transfer: dark to saturation spans {p.gain_dn_per_e * sat:.3g} DN (gain K x "
            f"{sat:.4g} e-), below {MIN_SPAN_DN:g} DN: nothing but quantisation ({settings})"
        )
    top = max_fraction * sat / e_per_unit if e_per_unit > 0 else math.inf
    if not top < float(np.finfo(np.float32).max):
        raise InputError(
            f"photon transfer: a white input gives {e_per_unit:.3g} photo-electrons; reaching "
            f"saturation needs an input level of {top:.3g}, beyond float32 ({settings})"
        )


def photon_transfer(
    preset="imx249",
    *,
    exposure_s=None,
    gain=None,
    temperature_c=None,
    n_levels: int = 50,
    patch: int = 256,
    max_fraction: float = 1.15,
    seed: int = 0,
    quantize: str = "round",
    progress=None,
) -> dict:
    """Simulate and analyse a photon-transfer series; returns measured/preset values, errors and curves.

    progress: optional callable(done_levels, n_levels).
    """
    if n_levels < 10:
        raise InputError(f"n_levels must be at least 10, got {n_levels}")
    if patch < 8:
        raise InputError(f"patch must be at least 8 pixels, got {patch}")
    p = _resolve(preset, exposure_s=exposure_s, gain=gain, temperature_c=temperature_c)
    gen = torch.Generator().manual_seed(seed)
    white = torch.ones(3, 1, 1, dtype=torch.float64)
    e_white = expected_electrons(white, p)[:, 0, 0]  # R, G, B photo-electrons for input (1, 1, 1)
    e_per_unit = e_white[1].item()
    check_measurable(p, e_per_unit, max_fraction)
    levels = np.linspace(0.0, max_fraction * p.saturation_e / e_per_unit, n_levels)
    masks = bayer_masks(p.cfa, patch, patch)
    green = masks[1].bool()
    # A flat field's mean electrons are the same in every pixel of a channel: compute them once per
    # level (the spectral step of simulate_raw) and sample the rest of Eq. 5 per pixel.
    e_mosaic = (masks * e_white.float()[:, None, None]).sum(0).expand(2, 1, patch, patch)
    means, variances = np.zeros(n_levels), np.zeros(n_levels)
    for i, v in enumerate(levels):
        raw = raw_from_electrons(float(v) * e_mosaic, p, noise=True, quantize=quantize, generator=gen).double()
        a, b = raw[0, 0][green], raw[1, 0][green]
        means[i] = 0.5 * (a.mean() + b.mean()).item()
        variances[i] = (a - b).var().item() / 2
        if progress is not None:
            progress(i + 1, n_levels)

    x = means - means[0]  # mu_y - mu_y.dark
    yv = variances - variances[0]
    i_sat = int(np.argmax(variances))
    x_sat = x[i_sat]
    fit = (x > 0) & (x <= 0.7 * x_sat)
    if fit.sum() < 2:
        raise InputError(
            f"photon transfer: only {int(fit.sum())} of {n_levels} levels fall below 70% of "
            f"saturation, too few to fit the gain K; use more --levels"
        )
    k = float(np.sum(x[fit] * yv[fit]) / np.sum(x[fit] ** 2))
    if not (math.isfinite(k) and k > 0):
        raise InputError(
            f"photon transfer: the fitted gain K = {k:g} DN/e- is not positive; "
            f"the simulated series shows no shot noise"
        )
    q = 1.0 / 12.0 if quantize in ("round", "uniform") else 0.0
    dark_e = math.sqrt(max(variances[0] - q, 0.0)) / k
    sat_e = x_sat / k

    mu_e = levels * e_per_unit  # the exposure axis: mean photo-electrons per green pixel
    lin = (x >= 0.05 * x_sat) & (x <= 0.95 * x_sat)
    slope, icpt = np.polyfit(mu_e[lin], x[lin], 1)
    dev = 100.0 * (x[lin] - (slope * mu_e[lin] + icpt)) / (slope * mu_e[lin] + icpt)
    linearity = float((dev.max() - dev.min()) / 2)

    warnings = []
    sd_dn = math.sqrt(variances[0])
    if sd_dn < 0.5:
        warnings.append(
            f"dark noise {sd_dn:.2f} DN is below 0.5 DN: quantisation dominates and the dark-noise "
            f"estimate is biased (EMVA 1288)"
        )
    if p.black_level_dn < 3 * p.gain_dn_per_e * p.dark_noise_e:
        warnings.append(
            f"black level {p.black_level_dn:g} DN is below 3 sigma of the dark noise: dark frames "
            f"clip at 0 DN, dark noise and gain estimates are biased"
        )
    if p.adc_limited:
        warnings.append("the ADC clips before full well: saturation is (ADC max - black level) / K")
    if i_sat == n_levels - 1:
        warnings.append("variance still rising at the brightest level: raise max_fraction")
    mu_i = dark_current_mean(p)
    ref_dark = math.sqrt(p.dark_noise_e**2 + mu_i)
    return {
        "preset": p.name,
        "channel": "G",
        "exposure_s": p.exposure_s,
        "temperature_c": p.temperature_c,
        "f_number": p.f_number,
        "quantize": quantize,
        "seed": seed,
        "n_levels": n_levels,
        "patch": patch,
        "pixels_per_frame": int(green.sum()),
        "measured_gain_dn_per_e": k,
        "preset_gain_dn_per_e": p.gain_dn_per_e,
        "gain_rel_err": k / p.gain_dn_per_e - 1,
        "measured_dark_noise_e": dark_e,
        "preset_dark_noise_e": p.dark_noise_e,
        "dark_current_e": mu_i,
        "reference_dark_noise_e": ref_dark,
        "dark_noise_rel_err": dark_e / ref_dark - 1,
        "measured_saturation_e": float(sat_e),
        "preset_full_well_e": p.full_well_e,
        "reference_saturation_e": p.saturation_e,
        "saturation_limited_by": "adc" if p.adc_limited else "full_well",
        "saturation_rel_err": float(sat_e / p.saturation_e - 1),
        "measured_saturation_dn": float(x_sat),
        "dark_mean_dn": float(means[0]),
        "dark_variance_dn2": float(variances[0]),
        "linearity_error_pct": linearity,
        "fit_range": [0.0, float(0.7 * x_sat)],
        "n_fit_points": int(fit.sum()),
        "compared": COMPARED,
        "warnings": warnings,
        "curves": {
            "input_level": levels.tolist(),
            "mean_photoelectrons": mu_e.tolist(),
            "mean_dn": means.tolist(),
            "mean_minus_dark_dn": x.tolist(),
            "variance_dn2": variances.tolist(),
            "fit_mask": fit.tolist(),
            "saturation_index": i_sat,
        },
    }


def save_ptc(result: dict, out_dir) -> dict:
    """Write ptc.json and ptc.png (variance vs mean with the fit; linearity) to out_dir; returns the paths."""
    import matplotlib

    from ..io import claim_out_dir  # strict JSON: non-finite -> null

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    claim_out_dir(out, "photon transfer curve", {"ptc.json", "ptc.png"})
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": str(out / "ptc.json"), "png": str(out / "ptc.png")}
    write_record_atomic(paths["json"], result)

    c = result["curves"]
    x, var = np.array(c["mean_minus_dark_dn"]), np.array(c["variance_dn2"])
    fit, k, i_sat = np.array(c["fit_mask"]), result["measured_gain_dn_per_e"], c["saturation_index"]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax.plot(x, var, "o", ms=3, label="simulated (2-frame difference)")
    ax.plot(x[fit], var[fit], "o", ms=3, color="tab:green", label="fit range (0-70% sat)")
    xs = np.linspace(0, x.max(), 100)
    ax.plot(xs, var[0] + k * xs, "-", color="k", lw=1, label=f"K = {k:.4f} DN/e-")
    ax.axvline(x[i_sat], color="tab:red", ls="--", lw=1, label=f"saturation {result['measured_saturation_e']:.0f} e-")
    ax.set_xlabel("mean signal minus dark (DN)")
    ax.set_ylabel("temporal variance (DN$^2$)")
    ax.set_title(
        f"photon transfer: {result['preset']}, {result['channel']} pixels, "
        f"dark noise {result['measured_dark_noise_e']:.2f} e-",
        fontsize=10,
    )
    ax.legend(fontsize=8)
    ax2.plot(c["mean_photoelectrons"], x, "o-", ms=3)
    ax2.set_xlabel("mean photo-electrons per pixel")
    ax2.set_ylabel("mean signal minus dark (DN)")
    ax2.set_title(f"linearity error {result['linearity_error_pct']:.2f}%", fontsize=10)
    fig.tight_layout()
    save_figure(fig, paths["png"], dpi=110)
    plt.close(fig)
    return paths
