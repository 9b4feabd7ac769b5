"""The optics surrogate (paper Sec. 4.1, Eq. 6-8): network, loss, checkpoint, training with
resume, evaluation, and the shipped paper-triplet-v1 model against the exact engine."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
import torch

from optix_e2e.dataset import DatasetSettings, generate
from optix_e2e.surrogate import (
    LossWeights,
    OpticsSurrogate,
    SurrogateConfig,
    SurrogateNet,
    SurrogateRangeError,
    optics_loss,
    optics_loss_terms,
)
from optix_e2e.surrogate.evaluate import SurrogateDataMismatch, evaluate, sample_metrics
from optix_e2e.surrogate.ground_truth import exact_arrays
from optix_e2e.surrogate.train import TrainConfig, train

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY = dict(hidden=32, depth=2, base_channels=16, n_up=2)


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    """24 paper-triplet-v1 designs at the dataset defaults, in 3 shards."""
    out = tmp_path_factory.mktemp("surrogate") / "data"
    generate("paper-triplet-v1", 24, 3, out, DatasetSettings(shard_size=8), progress=False)
    return out


@pytest.fixture(scope="module")
def held_out(tmp_path_factory):
    """16 designs the shipped surrogate never saw (another seed than its training data)."""
    out = tmp_path_factory.mktemp("surrogate") / "held_out"
    generate("paper-triplet-v1", 16, 7, out, DatasetSettings(shard_size=16), progress=False)
    return out


# ----- network and loss --------------------------------------------------------------------
def test_network_psf_is_energy_preserving_with_the_configured_shape():
    net = SurrogateNet(SurrogateConfig(n_params=5, psf_size=21, **TINY))
    psf, vig = net(torch.randn(7, 5), torch.rand(7))
    assert psf.shape == (7, 3, 21, 21) and vig.shape == (7, 3)
    assert torch.all(psf > 0)
    torch.testing.assert_close(psf.sum((-2, -1)), torch.ones(7, 3))
    for size, n_up in ((64, 4), (9, 0), (33, 3)):
        out, _ = SurrogateNet(
            SurrogateConfig(n_params=2, psf_size=size, hidden=8, depth=1, base_channels=8, n_up=n_up)
        )(torch.zeros(1, 2), torch.zeros(1))
        assert out.shape[-2:] == (size, size)
    with pytest.raises(ValueError, match=r"params must be \[B, 5\]"):
        net(torch.randn(2, 4), torch.rand(2))


def test_network_gradients_match_finite_differences():
    torch.manual_seed(0)
    net = SurrogateNet(SurrogateConfig(n_params=3, psf_size=9, hidden=8, depth=2, base_channels=8, n_up=1)).double()
    x, f = torch.randn(2, 3, dtype=torch.float64, requires_grad=True), torch.rand(2, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: torch.cat([o.reshape(-1) for o in net(p, f)]), (x,))


def test_loss_is_eq8_and_zero_only_at_the_target():
    torch.manual_seed(1)
    a = torch.softmax(torch.randn(4, 3, 81), -1).reshape(4, 3, 9, 9)
    b = torch.softmax(torch.randn(4, 3, 81), -1).reshape(4, 3, 9, 9)
    va, vb = torch.rand(4, 3), torch.rand(4, 3)
    assert optics_loss(a, va, a, va).item() == 0.0
    t = optics_loss_terms(a, va, b, vb)
    # the pixel term is the mean relative L1 error of unit-sum PSFs
    assert t["pixel"].item() == pytest.approx(float((a - b).abs().sum((-2, -1)).mean()))
    assert t["vignetting"].item() == pytest.approx(float((va - vb).abs().mean()))
    fa, fb = np.fft.fft2(a.numpy()), np.fft.fft2(b.numpy())
    assert t["fourier"].item() == pytest.approx(float(np.abs(fa - fb).mean()), rel=1e-5)
    d = (a - b).numpy()
    grad = (np.abs(np.diff(d, axis=-2)).sum((-2, -1)) + np.abs(np.diff(d, axis=-1)).sum((-2, -1))).mean()
    assert t["gradient"].item() == pytest.approx(float(grad), rel=1e-5)
    total = sum(t.values()).item()
    assert optics_loss(a, va, b, vb).item() == pytest.approx(total)
    assert optics_loss(a, va, b, vb, LossWeights(fourier=0, gradient=0)).item() == pytest.approx(
        (t["pixel"] + t["vignetting"]).item()
    )


def test_metrics_of_known_errors():
    exact = torch.zeros(1, 1, 1, 9, 9)
    exact[..., 4, 4] = 1.0
    guess = torch.zeros(1, 1, 1, 9, 9)
    guess[..., 4, 4], guess[..., 4, 6] = 0.8, 0.2  # 20% of the energy 2 px off
    m = sample_metrics(guess, torch.full((1, 1, 1), 0.9), exact, torch.ones(1, 1, 1))
    assert m["psf_rel_l1"].item() == pytest.approx(0.4)
    assert m["strehl_rel_err"].item() == pytest.approx(0.2)
    assert m["ee_abs_err"].item() == pytest.approx(0.2)  # EE(1 px): 0.8 vs 1
    assert m["vignetting_abs_err"].item() == pytest.approx(0.1)
    assert m["psf_rel_l2"].item() == pytest.approx(float(np.hypot(0.2, 0.2)))


# ----- training, checkpoints, evaluation ----------------------------------------------------
def _cfg(**kw) -> TrainConfig:
    return TrainConfig(
        **{**TINY, "steps": 30, "batch": 16, "val_designs": 4, "val_every": 10, "warmup": 5, "device": "cpu", **kw}
    )


def test_train_writes_checkpoints_and_resumes(tiny_data, tmp_path):
    out = tmp_path / "run"
    s1 = train(tiny_data, out, _cfg(), progress=False, stop_after=20)  # interrupted at step 20
    assert s1["steps_done"] == 20 and (out / "surrogate.pt").is_file() and (out / "state.pt").is_file()
    assert list((out / "tb").glob("events.*"))
    assert s1["data"]["n_train_designs"] == 20 and s1["data"]["n_val_designs"] == 4
    logs = []
    s2 = train(tiny_data, out, _cfg(steps=30), progress=False, log=logs.append)
    assert s2["steps_done"] == 30 and "at step 20" in logs[0]
    assert [h["step"] for h in s2["history"]] == [10, 20, 30]
    # a resumed run follows the same path as an uninterrupted one
    s3 = train(tiny_data, tmp_path / "straight", _cfg(steps=30), progress=False)
    assert s3["history"][-1]["psf_rel_l1_median"] == pytest.approx(s2["history"][-1]["psf_rel_l1_median"], rel=1e-4)
    with pytest.raises(ValueError, match="other settings.*hidden"):
        train(tiny_data, out, _cfg(steps=40, hidden=48), progress=False)


def test_checkpoint_round_trip_and_range_checks(tiny_data, tmp_path):
    train(tiny_data, tmp_path / "run", _cfg(steps=10), progress=False)
    m = OpticsSurrogate.load(tmp_path / "run")
    assert (
        m.manifest["designs_csv_sha256"] == json.loads((tiny_data / "manifest.json").read_text())["designs_csv_sha256"]
    )
    mid = (m.param_min + m.param_max).float() / 2
    psf, vig = m.psfs(mid)
    assert psf.shape == (13, 3, 21, 21) and vig.shape == (13, 3)
    m.save(tmp_path / "half.pt", half=True)
    h = OpticsSurrogate.load(tmp_path / "half.pt")
    psf_h, _ = h.psfs(mid)
    assert (psf_h - psf).abs().sum((-2, -1)).max() < 0.02  # fp16 weights: < 2% L1
    bad = mid.clone()
    bad[2] = float(m.param_max[2]) + 0.5
    with pytest.raises(SurrogateRangeError, match=m.param_names[2]):
        m.psfs(bad)
    m.out_of_range = "warn"
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        m.psfs(bad)
    assert any(m.param_names[2] in str(x.message) for x in w)
    with pytest.raises(SurrogateRangeError, match="field"):
        OpticsSurrogate.load(tmp_path / "run")(mid, torch.tensor([1.5]))


def test_eval_uses_held_out_designs_and_writes_a_grid(tiny_data, tmp_path):
    train(tiny_data, tmp_path / "run", _cfg(steps=10), progress=False)
    m = OpticsSurrogate.load(tmp_path / "run")
    rep = evaluate(m, tiny_data, png=tmp_path / "grid.png")
    assert rep["n_designs"] == 4 and rep["held_out"].startswith("validation")
    assert set(rep["overall"]) == {"psf_rel_l1", "psf_rel_l2", "strehl_rel_err", "ee_abs_err", "vignetting_abs_err"}
    assert len(rep["per_field"]) == 13
    assert rep["psf_rel_l1_median"] == rep["overall"]["psf_rel_l1"]["median"] > 0
    assert (tmp_path / "grid.png").stat().st_size > 10_000


def test_eval_refuses_data_of_other_settings(tiny_data, tmp_path):
    other = tmp_path / "other"
    generate("paper-triplet-v1", 4, 0, other, DatasetSettings(shard_size=4, sensor_pixel_um=3.0), progress=False)
    train(tiny_data, tmp_path / "run", _cfg(steps=5), progress=False)
    with pytest.raises(SurrogateDataMismatch, match="sensor_pixel_um|grid"):
        evaluate(OpticsSurrogate.load(tmp_path / "run"), other)


def test_eval_takes_data_of_the_other_focus_rule_where_it_moved_no_plane(tiny_data, tmp_path):
    """The shipped surrogate's data put each image plane wherever the focus fell (focus_within
    "none", before 2026-11-28); today's data keeps it behind the back-focus limit ("bfd"). The
    records differ only where a plane sits at or short of the limit: data with none such is
    evaluated, data with one is refused, naming both rules."""
    shipped = OpticsSurrogate.load("paper-triplet-v1")
    man = json.loads((tiny_data / "manifest.json").read_text())
    assert man["settings"]["focus_within"] == "bfd" and "focus_within" not in shipped.manifest["settings"]
    assert evaluate(shipped, tiny_data)["n_designs"] == 24
    moved = tmp_path / "moved"
    shutil.copytree(tiny_data, moved)
    # a writer's temporary shard folder (a stopped run's) is not read
    tmp = moved / "shards" / ".00000.tmp-123"
    tmp.mkdir()
    (tmp / "image_distance.npy").write_bytes(b"half-written")
    assert evaluate(shipped, moved)["n_designs"] == 24
    f = moved / "shards" / "00000" / "image_distance.npy"
    z = np.load(f)
    z[0] = man["space"]["constraints"]["min_bfd"]  # a design the limit held back
    np.save(f, z)
    with pytest.raises(SurrogateDataMismatch, match="focus_within: 'bfd' here, 'none' in its training data"):
        evaluate(shipped, moved)


def test_exact_engine_reproduces_the_dataset_record(tiny_data):
    man = json.loads((tiny_data / "manifest.json").read_text())
    shard = tiny_data / "shards" / "00001"
    params = np.load(shard / "params.npy")
    arrays, meta = exact_arrays(man, params[:3])
    assert meta["n_failed"] == 0
    np.testing.assert_array_equal(arrays["psf_sensor"], np.load(shard / "psf_sensor.npy")[:3])
    np.testing.assert_array_equal(arrays["relative_illumination"], np.load(shard / "relative_illumination.npy")[:3])


# ----- command line -------------------------------------------------------------------------
def test_cli_train_and_eval(tiny_data, tmp_path):
    from click.testing import CliRunner

    from optix_e2e.cli import main

    def run(*args):
        return CliRunner().invoke(main, [str(a) for a in args])

    r = run(
        "surrogate",
        "train",
        tiny_data,
        "--out",
        tmp_path / "run",
        "--steps",
        6,
        "--batch",
        8,
        "--hidden",
        16,
        "--depth",
        1,
        "--base-channels",
        8,
        "--val-designs",
        4,
        "--val-every",
        3,
        "--device",
        "cpu",
        "--json",
    )
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["steps_done"] == 6
    # the shipped model on designs it never saw (this dataset's seed is not its training seed)
    r = run("surrogate", "eval", "paper-triplet-v1", tiny_data, "--json", "--out", tmp_path / "ev")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["n_designs"] == 24 and rep["model"].endswith("surrogate_paper_triplet.pt")
    for key in ("psf_rel_l1_median", "vignetting_abs_err_median", "strehl_rel_err_median", "ee_abs_err_median"):
        assert np.isfinite(rep[key])
    assert (tmp_path / "ev" / "eval.json").is_file() and (tmp_path / "ev" / "grid.png").is_file()
    r = run("surrogate", "eval", tmp_path / "nothing.pt", tiny_data)
    assert r.exit_code == 1 and "no such surrogate file" in r.output


def test_eval_refuses_a_dataset_whose_psfs_hold_no_light(tiny_data, tmp_path):
    """A shard whose sensor PSFs were zeroed with a checksum forged to match: ``surrogate eval``
    says so in one line and points at ``dataset verify``, not an exit 0 with NaN medians."""
    from click.testing import CliRunner

    from optix_e2e.cli import main
    from optix_e2e.dataset.layout import crc32_file

    data = tmp_path / "data"
    shutil.copytree(tiny_data, data)
    shard = data / "shards" / "00000"
    p = shard / "psf_sensor.npy"
    np.save(p, np.zeros_like(np.load(p)))
    meta = json.loads((shard / "shard.json").read_text())
    meta["files"]["psf_sensor"]["crc32"] = crc32_file(p)
    (shard / "shard.json").write_text(json.dumps(meta))
    r = CliRunner().invoke(main, ["surrogate", "eval", "paper-triplet-v1", str(data), "--json"])
    assert r.exit_code == 1 and "hold no light" in r.output and "dataset verify" in r.output, r.output
    assert "Traceback" not in r.output and "NaN" not in r.output


def test_eval_writes_only_into_its_own_folder(tiny_data, tmp_path):
    """``surrogate eval --out`` into a folder holding another command's eval.json (``isp eval``
    writes one too) or a design run: refused before any work, the files left as they were;
    into its own earlier output it writes again."""
    from click.testing import CliRunner

    from optix_e2e.cli import main

    def ev(out):
        return CliRunner().invoke(main, ["surrogate", "eval", "paper-triplet-v1", str(tiny_data), "--out", str(out)])

    other = tmp_path / "isp"
    other.mkdir()
    (other / "eval.json").write_text('{"psnr_db": 30.0}')
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")
    for folder, kept in ((other, "eval.json"), (run, "config.json")):
        before = (folder / kept).read_text()
        r = ev(folder)
        assert r.exit_code == 1 and "choose another --out" in r.output, r.output
        assert sorted(p.name for p in folder.iterdir()) == [kept] and (folder / kept).read_text() == before
    own = tmp_path / "own"
    assert ev(own).exit_code == 0 and ev(own).exit_code == 0  # its own folder: written again
    assert json.loads((own / "eval.json").read_text())["n_designs"] == 24
