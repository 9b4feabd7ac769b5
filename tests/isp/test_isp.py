"""ISP stage: the reference ISP, the bilinear demosaick layer, the proxy and the software ISP."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest
import torch

from optix_e2e import scenes
from optix_e2e.isp import ISPProxy, SoftwareISP, bilinear_demosaick, ccm, data, reference
from optix_e2e.isp import params as hp
from optix_e2e.sensor import PATTERNS, get_preset, mosaic, simulate_raw

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def raw_scene():
    """A dead-leaves chart captured by the default sensor: RAW [1, 1, 64, 64] in DN."""
    scene = scenes.dead_leaves(64, 3, colors="uniform")[None]
    raw, ideal = data.capture_raw(
        scene, np.random.default_rng(0), data.Capture(level_min=0.6, level_max=0.6), torch.Generator().manual_seed(0)
    )
    return raw, ideal


# --- hyperparameters ---------------------------------------------------------------------


def test_space_has_at_least_eight_hyperparameters_in_physical_ranges():
    assert len(hp.SPACE) >= 8
    for p in hp.SPACE:
        assert p.low < p.high and p.low <= p.default <= p.high, p.name
    u = hp.to_unit(hp.defaults())
    assert np.allclose(list(hp.from_unit(u).values()), list(hp.defaults().values()))


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"gamma": 9.0}, "gamma=9.0 outside"),
        ({"sharpness": 1}, "unknown"),
        ({"demosaick": "ahd"}, "demosaick"),
        ({"wb_red": float("nan")}, "wb_red"),
    ],
)
def test_bad_hyperparameters_are_named(bad, match):
    with pytest.raises(ValueError, match=match):
        hp.check(bad)


def test_reference_isp_rejects_bad_raw():
    with pytest.raises(ValueError, match="NaN"):
        reference.run(np.full((8, 8), np.nan))
    with pytest.raises(ValueError, match="one RAW frame"):
        reference.run(np.zeros((2, 8, 8)))


# --- demosaicking --------------------------------------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
def test_torch_and_numpy_bilinear_demosaick_agree_and_keep_flat_colour(pattern):
    rgb = torch.rand(1, 3, 24, 20, dtype=torch.float64)
    cfa = mosaic(rgb, pattern)
    ours = bilinear_demosaick(cfa, pattern)[0].permute(1, 2, 0).numpy()
    ref = reference.demosaick_bilinear(cfa[0, 0].numpy(), pattern)
    assert np.allclose(ours, ref, atol=1e-12)
    flat = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)[None, :, None, None].expand(1, 3, 12, 12)
    out = bilinear_demosaick(mosaic(flat, pattern), pattern)
    assert torch.allclose(out, flat, atol=1e-12)  # border included: reflect padding keeps the phase


@pytest.mark.parametrize("pattern", PATTERNS)
def test_malvar_is_exact_on_linear_ramps(pattern):
    # Bilinear interpolation is exact on a linear ramp and Malvar's Laplacian correction vanishes
    # there, so the interior must be reproduced to rounding error.
    y, x = np.mgrid[0:20, 0:20].astype(float)
    rgb = np.stack([0.1 + 0.01 * x, 0.2 + 0.005 * x + 0.01 * y, 0.9 - 0.02 * y], axis=-1)
    cfa = mosaic(torch.from_numpy(rgb.transpose(2, 0, 1)), pattern)[0].numpy()
    out = reference.demosaick_malvar(cfa, pattern)
    assert np.abs(out[3:-3, 3:-3] - rgb[3:-3, 3:-3]).max() < 1e-12


def test_bilinear_demosaick_gradcheck():
    cfa = torch.rand(1, 1, 6, 8, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c: bilinear_demosaick(c, "GRBG"), (cfa,))


# --- the reference ISP -----------------------------------------------------------------------


def test_colour_matrix_maps_the_chart_close_to_its_true_colours():
    m = ccm.sensor_ccm()
    assert np.allclose(m.sum(axis=1), 1.0)
    from optix_e2e import color

    target = color.colorchecker_srgb(linear=True).double().numpy()
    cam = ccm.camera_rgb(target * 0.8)
    white = int(np.argmax(target.sum(1)))
    cam = cam / cam[white] * target[white]
    before = np.abs(cam - target).mean()
    after = np.abs(cam @ m.T - target).mean()
    assert after < 0.5 * before and after < 0.02, (before, after)


def test_every_hyperparameter_changes_the_output(raw_scene):
    raw = raw_scene[0][0, 0].numpy()
    base = hp.defaults()
    ref = reference.run(raw, base)
    assert ref.shape == (64, 64, 3) and ref.min() >= 0 and ref.max() <= 1
    assert np.allclose(ref * 255, np.round(ref * 255))  # 8-bit output
    for p in hp.SPACE:
        lo, hi = reference.run(raw, {**base, p.name: p.low}), reference.run(raw, {**base, p.name: p.high})
        assert np.abs(lo - hi).mean() > 2e-3, p.name


def test_flat_field_stays_flat_under_every_stage():
    # Denoising, sharpening, colour matrix and tone curve must not invent structure on a flat
    # field (this caught scikit-image's unsharp_mask slicing the wrong axis for channel_axis=-1).
    rng = np.random.default_rng(1)
    for _ in range(3):
        p = hp.sample(rng)
        p["wb_red"] = p["wb_blue"] = 1.0
        out = reference.run(np.full((32, 32), 1500.0), p)
        assert np.ptp(out.reshape(-1, 3), axis=0).max() <= 1 / 255 + 1e-9, p


def test_default_isp_with_white_balance_renders_a_grey_card_neutral():
    preset = get_preset("imx249")
    grey = torch.full((1, 3, 16, 16), 0.18)
    raw = simulate_raw(grey, preset, noise=False, quantize="none")[0, 0].numpy()
    resp = ccm.camera_rgb(np.array([[0.18, 0.18, 0.18]]))[0]
    wb = {"wb_red": resp[1] / resp[0], "wb_blue": resp[1] / resp[2], "sharpen_amount": 0.0}
    out = reference.run(raw, wb)[4:-4, 4:-4].reshape(-1, 3).mean(0)
    assert np.ptp(out) < 0.01, out
    # green signal above black, over the ISP's white level, through the 2.2 tone curve
    expected = (resp[1] / (2**preset.adc_bits - 1 - preset.black_level_dn)) ** (1 / 2.2)
    assert abs(out.mean() - expected) < 0.01, (out.mean(), expected)


# --- proxy and software ISP -------------------------------------------------------------------


def test_proxy_gradients_reach_raw_and_hyperparameters():
    torch.manual_seed(0)
    model = ISPProxy(base=8, depth=2)
    raw = (torch.rand(2, 1, 20, 28) * 4000).requires_grad_(True)  # not a multiple of 8: padded
    u = torch.rand(2, len(hp.SPACE), requires_grad=True)
    out = model(raw, u)
    assert out.shape == (2, 3, 20, 28)
    out.mean().backward()
    assert torch.isfinite(raw.grad).all() and raw.grad.abs().sum() > 0
    assert torch.isfinite(u.grad).all() and (u.grad.abs() > 0).all()


def test_proxy_rejects_wrong_hyperparameter_shape():
    with pytest.raises(ValueError, match="hyperparameters"):
        ISPProxy(base=8, depth=2)(torch.zeros(1, 1, 16, 16), torch.zeros(1, 3))


def test_proxy_save_load_round_trip_and_bad_files(tmp_path):
    model = ISPProxy(base=8, depth=2)
    model.save(tmp_path / "p.pt", note="x")
    back = ISPProxy.load(tmp_path / "p.pt")
    raw, u = torch.rand(1, 1, 16, 16) * 4000, torch.rand(1, len(hp.SPACE))
    with torch.no_grad():
        assert torch.allclose(model.half().float()(raw, u), back(raw, u), atol=1e-3)
    assert back.meta["note"] == "x"
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        ISPProxy.load(tmp_path / "bad.pt")
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        ISPProxy.load(tmp_path / "missing.pt")


@pytest.mark.slow
def test_software_isp_pretraining_learns_and_resumes(tmp_path):
    # tiny shapes: the mechanism (pools through lenses of the space, the loss falls, the
    # validation curve, state.pt continues the same run, the float16 export loads)
    from optix_e2e.camera_design.isp_pretraining import PretrainConfig, pretrain

    cfg = PretrainConfig(
        steps=16,
        batch=2,
        crop=32,
        pool=8,
        pool_steps=8,
        width=8,
        depth=2,
        val_size=4,
        val_every=8,
        checkpoint_every=4,
        lr=2e-3,
        threads=1,
    )
    first = pretrain(dataclasses.replace(cfg, steps=8), tmp_path, progress=False, log=lambda m: None)
    assert first["steps"] == 8 and (tmp_path / "state.pt").is_file()
    said = []
    meta = pretrain(cfg, tmp_path, progress=False, log=said.append)
    assert said and "resuming ISP pre-training at step 8" in said[0]
    assert meta["steps"] == 16 and [c["step"] for c in meta["curve"]] == [8, 16]
    assert (tmp_path / "curve.csv").read_text().count("\n") == 3 and list((tmp_path / "tb").iterdir())
    back = SoftwareISP.load(tmp_path / "software_isp.pt")
    assert back.meta["steps"] == 16 and back.config()["arch"] == "nafnet"
    with pytest.raises(ValueError, match="other settings"):
        pretrain(dataclasses.replace(cfg, width=16), tmp_path, progress=False)
    # a damaged state (other weight keys; no step): one error naming it, not a traceback
    good = torch.load(tmp_path / "state.pt", weights_only=True)
    for i, damage in enumerate((lambda st: st["model"].pop(next(iter(st["model"]))), lambda st: st.pop("step"))):
        copy = tmp_path.parent / f"{tmp_path.name}-damaged{i}"  # the run folder with only its state changed
        shutil.copytree(tmp_path, copy)
        st = {**good, "model": dict(good["model"])}
        damage(st)
        torch.save(st, copy / "state.pt")
        with pytest.raises(ValueError, match="damaged ISP pre-training state"):
            pretrain(cfg, copy, progress=False)
    # a new run from those weights (--init): the record of the first run is kept
    said = []
    again = pretrain(
        dataclasses.replace(cfg, steps=2, seed=1),
        tmp_path / "next",
        init=tmp_path / "software_isp.pt",
        progress=False,
        log=said.append,
    )
    assert "starting from the weights of" in said[0] and again["earlier_training"][0]["steps"] == 16
    (tmp_path / "design").mkdir()  # a folder with another run's files is refused, left as it was
    (tmp_path / "design" / "train.json").write_text("{}")
    with pytest.raises(ValueError, match="holds no ISP pre-training"):
        pretrain(cfg, tmp_path / "design", progress=False)
    assert [p.name for p in (tmp_path / "design").iterdir()] == ["train.json"]
    assert (tmp_path / "design" / "train.json").read_text() == "{}"
    with pytest.raises(ValueError, match="not the"):
        pretrain(
            dataclasses.replace(cfg, width=16), tmp_path / "other", init=tmp_path / "software_isp.pt", progress=False
        )


@pytest.mark.parametrize("pattern", PATTERNS)
def test_torch_malvar_matches_the_reference_isp(pattern):
    from optix_e2e.isp.classical import malvar_demosaick

    cfa = torch.rand(1, 1, 24, 30, dtype=torch.float64)
    ref = reference.demosaick_malvar(cfa[0, 0].numpy(), pattern)
    assert np.allclose(malvar_demosaick(cfa, pattern)[0].permute(1, 2, 0).numpy(), ref, atol=1e-12)


def test_classical_pipeline_recovers_greys_and_colours():
    # the calibrated 3x3 inverts the sensor model on the grey axis (to 1e-3 in sRGB) and on the
    # ColorChecker to 3e-3 on average; the saturated red keeps 0.05 (the spectral model's
    # interpolation goes negative there and is clipped: no 3x3 undoes that)
    from optix_e2e import color
    from optix_e2e.camera import calibrated_preset
    from optix_e2e.isp.classical import ClassicalISP

    p = calibrated_preset("imx249", 4.4)
    isp = ClassicalISP(p)
    for patches, worst, mean in (
        (torch.tensor([[0.05] * 3, [0.2] * 3, [0.6] * 3]), 1e-3, 1e-3),
        (color.colorchecker_srgb(linear=True) * 0.8, 0.06, 3e-3),
    ):
        scene = patches[:, :, None, None].expand(-1, -1, 8, 8).contiguous()
        raw = simulate_raw(scene, p, noise=False, quantize="none")
        err = (isp(raw)[:, :, 4, 4] - color.linear_to_srgb(patches)).abs()
        assert err.max() < worst and err.mean() < mean, err


def test_software_isp_starts_as_the_classical_pipeline_and_sees_the_position():
    from optix_e2e.isp.classical import ClassicalISP

    raw = 64 + 3000 * torch.rand(2, 1, 32, 48)
    isp = SoftwareISP(base=8, depth=2)
    with torch.no_grad():
        assert torch.equal(isp(raw, (0.0, 0.0), 1131.0), ClassicalISP()(raw))  # zero-initialized correction
        torch.nn.init.normal_(isp.body.head.weight, std=0.1)
        a, b = isp(raw, (0.0, 0.0), 1131.0), isp(raw, (500.0, 800.0), 1131.0)
        per_sample = isp(raw, torch.tensor([[0.0, 0.0], [500.0, 800.0]]), 1131.0)
    assert not torch.allclose(a, b)  # the position reaches the output
    assert torch.allclose(per_sample[0], a[0]) and torch.allclose(per_sample[1], b[1])
    with pytest.raises(ValueError, match="full_field_px"):
        isp(raw)


# --- the shipped proxy -------------------------------------------------------------------------


def test_shipped_proxy_imitates_the_reference_isp_on_held_out_photos():
    from optix_e2e.isp.evaluate import evaluate_proxy

    res = evaluate_proxy(ISPProxy.load(), size=128, n_param_sets=2, photos=["coffee", "rocket"], progress=False)
    assert res["n_param_sets"] == 3 and len(res["per_case"]) == 6
    assert res["proxy_psnr_db"] > 30.0 and res["proxy_ssim"] > 0.9, res


@pytest.mark.slow
def test_tuning_through_the_proxy_improves_the_true_isp():
    from optix_e2e.isp.tune import true_isp_quality, tune_params

    tuned, history = tune_params(ISPProxy.load(), steps=60, n_scenes=16, size=64, progress=False)
    assert np.mean(history[-10:]) < np.mean(history[:10])
    photos = ["astronaut", "chelsea"]
    before = true_isp_quality(hp.defaults(), size=128, photos=photos)
    after = true_isp_quality(tuned, size=128, photos=photos)
    assert after["psnr_db"] > before["psnr_db"] + 1.0, (before["psnr_db"], after["psnr_db"])


def test_cli_isp_eval_json_and_errors(tmp_path):
    import json

    from click.testing import CliRunner

    from optix_e2e.cli import main

    r = CliRunner().invoke(main, ["isp", "eval", "--json", "--photo", "coffee", "--size", "64", "--param-sets", "1"])
    assert r.exit_code == 0, r.output
    res = json.loads(r.stdout)
    assert {"proxy_psnr_db", "proxy_ssim", "proxy_haarpsi", "per_case"} <= set(res)
    r = CliRunner().invoke(main, ["isp", "eval", str(tmp_path / "nope.pt")])
    assert r.exit_code == 1 and "nope.pt" in r.output
    r = CliRunner().invoke(main, ["isp", "params", "--json"])
    assert r.exit_code == 0 and len(json.loads(r.stdout)) >= 8
