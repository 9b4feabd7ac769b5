"""Differentiable EMVA 1288 sensor model (paper Sec. 3.3, Eqs. 3-5), photon transfer and CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from optix_e2e.cli.sensor import sensor
from optix_e2e.sensor import (
    PATTERNS,
    PRESETS,
    Sensor,
    SensorPreset,
    bayer_masks,
    dark_current_mean,
    expected_electrons,
    get_preset,
    photon_count_mean,
    photon_transfer,
    poisson_sample,
    rgb_to_spectrum,
    simulate_raw,
)
from optix_e2e.sensor.poisson import pathwise
from optix_e2e.sensor.spectral import ANCHORS_NM, WAVELENGTHS_NM

IMX = get_preset("imx249")


def flat(value, b=2, size=64, dtype=torch.float32):
    return torch.full((b, 3, size, size), float(value), dtype=dtype)


# (a) photon transfer recovers the preset -------------------------------------------------------------


@pytest.fixture(scope="module")
def ptc_imx():
    return photon_transfer("imx249")


def test_ptc_recovers_gain_dark_noise_and_saturation(ptc_imx):
    r = ptc_imx
    assert abs(r["gain_rel_err"]) < 0.05, r["measured_gain_dn_per_e"]
    assert abs(r["dark_noise_rel_err"]) < 0.05, r["measured_dark_noise_e"]
    assert abs(r["saturation_rel_err"]) < 0.05, r["measured_saturation_e"]
    # the EMVA saturation (variance peak) sits at or just below full well, never above
    assert r["measured_saturation_e"] <= r["preset_full_well_e"] * 1.002
    assert r["saturation_limited_by"] == "full_well" and r["warnings"] == []
    assert r["linearity_error_pct"] < 1.0
    assert r["n_levels"] == 50 and len(r["curves"]["variance_dn2"]) == 50


def test_ptc_flags_adc_limited_low_light():
    r = photon_transfer(IMX.low_light(100), n_levels=20, patch=64)
    assert r["saturation_limited_by"] == "adc"
    assert any("ADC clips" in w for w in r["warnings"])
    assert any("black level" in w for w in r["warnings"])  # 64 DN black vs 84 DN of dark noise at K = 12


# (b) noise statistics of flat fields match Eq. 5 ------------------------------------------------------


@pytest.mark.parametrize("quantize", ["uniform", "round"])
def test_flat_field_mean_and_variance_match_model(quantize):
    p, gen = IMX, torch.Generator().manual_seed(1)
    masks = bayer_masks(p.cfa, 256, 256).bool()
    e_white = expected_electrons(torch.ones(3, 1, 1, dtype=torch.float64), p)[:, 0, 0]
    mu_i = dark_current_mean(p)
    for level in (0.0, 0.05, 0.3, 0.7):
        raw = simulate_raw(flat(level, size=256), p, quantize=quantize, generator=gen).double()
        for c in range(3):
            y = raw[:, 0][:, masks[c]]  # [2, n]
            mu_e = level * e_white[c].item() + mu_i
            mean_model = p.black_level_dn + p.gain_dn_per_e * mu_e
            var_model = p.gain_dn_per_e**2 * (mu_e + p.dark_noise_e**2) + 1 / 12
            n = y.numel()
            # mean within 5 standard errors; variance within 5 relative standard errors sqrt(2/n) (~4%)
            assert abs(y.mean().item() - mean_model) < 5 * math.sqrt(var_model / n), (level, c)
            assert abs(y.var().item() / var_model - 1) < 5 * math.sqrt(2 / n), (level, c, y.var().item(), var_model)


# (c) Poisson sampler and its gradient estimator -----------------------------------------------------


def test_poisson_gradient_estimator_matches_analytic_derivatives():
    torch.manual_seed(0)
    n = 200_000
    mu = torch.tensor([0.5, 3.0, 20.0, 200.0], dtype=torch.float64, requires_grad=True)
    gen = torch.Generator().manual_seed(0)
    k = poisson_sample(mu.expand(n, 4), generator=gen)
    assert torch.equal(k, k.round())  # the forward values are exact integer draws
    (g1,) = torch.autograd.grad(k.mean(0).sum(), mu, retain_graph=True)
    (g2,) = torch.autograd.grad((k**2).mean(0).sum(), mu)
    # d E[k]/d mu = 1 for every rate (standard error <= 0.003 here)
    assert torch.allclose(g1, torch.ones(4, dtype=torch.float64), atol=0.01), g1
    # d E[k^2]/d mu = 1 + 2 mu, exact for rates >= min_rate (= 1); relative standard error < 0.2%
    target = 1 + 2 * mu.detach()
    assert torch.allclose(g2[1:], target[1:], rtol=0.01), (g2, target)
    # the naive straight-through estimator misses the +1 (2 mu): 6 instead of 7 at mu = 3
    mu3 = torch.tensor(3.0, dtype=torch.float64, requires_grad=True)
    k3 = poisson_sample(mu3.expand(n), generator=gen, estimator="straight_through")
    (g3,) = torch.autograd.grad((k3**2).mean(), mu3)
    assert abs(g3.item() - 6.0) < 0.1


def test_poisson_pathwise_gradcheck_and_reproducibility():
    rate = (torch.rand(3, 5, dtype=torch.float64) * 50 + 2).requires_grad_()
    eps = torch.randn(3, 5, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda r: pathwise(r, eps), (rate,))
    a = poisson_sample(rate, generator=torch.Generator().manual_seed(7))
    b = poisson_sample(rate, generator=torch.Generator().manual_seed(7))
    c = poisson_sample(rate, generator=torch.Generator().manual_seed(8))
    assert torch.equal(a, b) and not torch.equal(a, c)


# (d) gradients flow from RAW back to the image ------------------------------------------------------


def test_simulate_raw_gradcheck_noise_free():
    x = torch.rand(1, 3, 4, 4, generator=torch.Generator().manual_seed(3), dtype=torch.float64) * 0.4 + 0.1
    x.requires_grad_()
    assert torch.autograd.gradcheck(lambda t: simulate_raw(t, IMX, noise=False, quantize="none"), (x,))


@pytest.mark.parametrize("quantize", ["uniform", "round"])
def test_gradient_flows_through_noisy_sensor(quantize):
    x = (torch.rand(2, 3, 16, 16) * 0.6).requires_grad_()
    raw = simulate_raw(x, IMX, quantize=quantize, generator=torch.Generator().manual_seed(0))
    assert raw.shape == (2, 1, 16, 16) and raw.dtype == torch.float32
    raw.sum().backward()
    assert torch.isfinite(x.grad).all()
    assert (x.grad.abs().sum(dim=(0, 2, 3)) > 0).all()  # every input channel reaches the RAW


def test_sensor_module_matches_function_and_exposure_attribute():
    x = torch.rand(1, 3, 8, 8) * 0.3
    s = Sensor("imx249", noise=False)
    y1 = s(x)
    assert torch.allclose(y1, simulate_raw(x, IMX, noise=False))
    s.exposure_s = 2 * IMX.exposure_s
    y2 = s(x)
    b, mu_i = IMX.black_level_dn, IMX.gain_dn_per_e * dark_current_mean(IMX)
    assert torch.allclose(y2 - b - 2 * mu_i, 2 * (y1 - b - mu_i), rtol=1e-4, atol=1e-3)
    assert simulate_raw(x[0], IMX, noise=False).shape == (1, 8, 8)


# (e) Eq. 3 photon count against a hand calculation -------------------------------------------------


def test_eq3_photon_count_one_band_by_hand():
    # band 25: 553 nm, 6 nm wide; L = 0.02 W m^-2 sr^-1 nm^-1, 5.86 um pixel, 5 ms, f/4:
    # E = pi * 0.02 * 6 / (1 + 8^2) = 5.7999e-3 W/m^2; * A (3.4340e-11 m^2) = 1.99165e-13 W;
    # * 5 ms = 9.95825e-16 J; / (h c / 553 nm = 3.59213e-19 J) = 2772.24 photons
    assert WAVELENGTHS_NM[25] == 553.0
    radiance = torch.zeros(50, 1, 1, dtype=torch.float64)
    radiance[25] = 0.02
    mu = photon_count_mean(radiance, pixel_um=5.86, exposure_s=5e-3, f_number=4.0)
    assert mu[25, 0, 0].item() == pytest.approx(2772.24, rel=1e-5)
    assert mu.sum().item() == pytest.approx(mu[25, 0, 0].item())


def test_spectrum_interpolation_and_white_calibration():
    grey = torch.full((3, 2, 2), 0.4)
    assert torch.allclose(rgb_to_spectrum(grey), torch.full((50, 2, 2), 0.4), atol=1e-6)  # flat
    rgb = torch.tensor([0.2, 0.7, 0.5])[:, None, None]
    spec = rgb_to_spectrum(rgb)[:, 0, 0]
    assert (spec >= 0).all()
    lam = torch.tensor(WAVELENGTHS_NM)
    for c, a in enumerate(ANCHORS_NM):  # the quadratic passes through R, G, B at their wavelengths
        assert np.interp(a, lam.numpy(), spec.numpy()) == pytest.approx(rgb[c, 0, 0].item(), abs=0.02)
    for p in PRESETS.values():  # radiance_scale: (1, 1, 1) -> 80-90% of full well in G
        g = expected_electrons(torch.ones(3, 1, 1, dtype=torch.float64), p)[1].item()
        assert 0.80 < g / p.full_well_e < 0.90, p.name
    qe = IMX.qe_curves(WAVELENGTHS_NM)
    assert qe[1].max().item() == pytest.approx(0.70, abs=0.01)
    assert lam[qe.argmax(1)].tolist() == sorted(lam[qe.argmax(1)].tolist(), reverse=True)  # R > G > B peaks


# (f) Eq. 4 dark current doubles every T_d ----------------------------------------------------------


def test_eq4_dark_current_doubles_per_doubling_interval():
    p = IMX
    ref = dark_current_mean(p, temperature_c=p.t_ref_c)
    assert ref == pytest.approx(p.dark_current_e_per_s * p.exposure_s)
    assert dark_current_mean(p, temperature_c=p.t_ref_c + p.doubling_c) == pytest.approx(2 * ref)
    assert dark_current_mean(p, temperature_c=p.t_ref_c + 3 * p.doubling_c) == pytest.approx(8 * ref)
    assert dark_current_mean(p, exposure_s=2 * p.exposure_s) == pytest.approx(2 * ref)
    hot = p.t_ref_c + 5 * p.doubling_c  # 32x: 0.8 e- at 5 ms
    dark = simulate_raw(torch.zeros(3, 4, 4), p, temperature_c=hot, noise=False)
    assert torch.allclose(dark - p.black_level_dn, torch.tensor(p.gain_dn_per_e * 32 * ref).float(), rtol=1e-4)


# (g) CFA phases put the right colour at the right pixel --------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
def test_cfa_phase_puts_each_channel_at_its_pixel(pattern):
    resp = torch.stack(
        [
            simulate_raw(torch.eye(3)[c][:, None, None].expand(3, 4, 4) * 0.5, IMX, cfa=pattern, noise=False)[0]
            - IMX.black_level_dn
            for c in range(3)
        ]
    )  # [3 inputs, 4, 4]
    expected = torch.tensor([["RGB".index(pattern[2 * (y % 2) + x % 2]) for x in range(4)] for y in range(4)])
    assert torch.equal(resp.argmax(0), expected)  # each pixel responds most to its own colour
    for c in range(3):  # and each colour lights its own pixels most
        own, other = resp[c][expected == c], resp[c][expected != c]
        assert own.min() > other.max()


# (h) low light: 100x less exposure, 100x gain, same mean DN ---------------------------------------


def test_low_light_same_mean_less_exposure_more_noise():
    low = IMX.low_light(100)
    assert low.exposure_s == pytest.approx(IMX.exposure_s / 100)
    assert low.gain_dn_per_e == pytest.approx(IMX.gain_dn_per_e * 100)
    x = torch.rand(1, 3, 8, 8) * 0.35
    assert torch.allclose(simulate_raw(x, low, noise=False), simulate_raw(x, IMX, noise=False), rtol=1e-4)
    gen = torch.Generator().manual_seed(5)
    g = bayer_masks(IMX.cfa, 64, 64)[1].bool()
    a = simulate_raw(flat(0.3, b=1), IMX, generator=gen)[0, 0][g]
    b = simulate_raw(flat(0.3, b=1), low, generator=gen)[0, 0][g]
    assert abs(a.mean() - b.mean()) < 5 * b.std() / math.sqrt(b.numel())  # same mean within noise
    assert b.std() > 5 * a.std()  # ~138 DN vs ~11 DN


# (i) bad input raises ValueError naming the parameter ---------------------------------------------


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: simulate_raw(flat(0.2), IMX, exposure_s=-1e-3), "exposure_s"),
        (lambda: simulate_raw(flat(0.2), IMX, gain=0), "gain"),
        (lambda: simulate_raw(flat(0.2), IMX, f_number=float("nan")), "f_number"),
        (lambda: simulate_raw(torch.full((1, 3, 4, 4), float("nan")), IMX), "linear_rgb"),
        (lambda: simulate_raw(torch.zeros(1, 4, 4, 4), IMX), "linear_rgb"),
        (lambda: simulate_raw(flat(0.2), "imx999"), "unknown sensor preset 'imx999'.*imx249"),
        (lambda: simulate_raw(flat(0.2), IMX, cfa="RGBW"), "cfa"),
        (lambda: simulate_raw(flat(0.2), IMX, quantize="floor"), "quantize"),
        (lambda: SensorPreset(full_well_e=-5), "full_well_e"),
        (lambda: SensorPreset(cfa="XYZW"), "cfa"),
        (lambda: IMX.with_(dark_noise_e=float("inf")), "dark_noise_e"),
        (lambda: IMX.low_light(0), "factor"),
        (lambda: poisson_sample(torch.ones(3), estimator="reinforce"), "estimator"),
    ],
)
def test_bad_input_raises_value_error_naming_parameter(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# (j) CLI --------------------------------------------------------------------------------------------


def test_cli_sensor_ptc_json_and_files(tmp_path):
    res = CliRunner().invoke(sensor, ["ptc", "--json", "--levels", "20", "--patch", "64", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    for key in (
        "gain_rel_err",
        "dark_noise_rel_err",
        "saturation_rel_err",
        "measured_gain_dn_per_e",
        "measured_dark_noise_e",
        "measured_saturation_e",
        "linearity_error_pct",
        "n_levels",
        "curves",
    ):
        assert key in data
    assert data["n_levels"] == 20 and abs(data["gain_rel_err"]) < 0.1
    assert (tmp_path / "ptc.png").stat().st_size > 0
    assert json.loads((tmp_path / "ptc.json").read_text())["preset"] == "imx249"


def test_cli_sensor_ptc_unknown_preset_is_one_line_error():
    res = CliRunner().invoke(sensor, ["ptc", "--preset", "nope"])
    assert res.exit_code == 1
    assert "Error: unknown sensor preset 'nope'" in res.output
