"""``--device`` on every command that runs torch (issue 36): each takes ``--device cpu`` in its
smallest form, and a GPU the machine lacks is one ``Error:`` line naming ``--device``, before
any folder is claimed."""

from __future__ import annotations

import json

import pytest
import torch


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    """Four labelled street scenes (a COCO folder) for the detector's commands."""
    from optix_e2e.scenes.coco import write_street_coco

    folder = tmp_path_factory.mktemp("street")
    write_street_coco(folder, 4, seed=0, size=(64, 96))
    return folder


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    """Eight paper-triplet-v1 designs: a PSF dataset for the surrogate's training."""
    from optix_e2e.dataset import DatasetSettings, generate

    out = tmp_path_factory.mktemp("surrogate") / "data"
    generate("paper-triplet-v1", 8, 3, out, DatasetSettings(shard_size=8), progress=False)
    return out


def commands(street, tiny_data, out):
    """Each torch command's smallest form, writing under ``out``."""
    return {
        "design": ["design", "iq-hardware", "--out", out / "design", "--budget", "smoke", "--threads", "1", "--quiet"],
        "detect train": ["detect", "train", street, "--out", out / "det", "--steps", "2", "--batch", "2", "--quiet"],
        "isp train-proxy": [
            *("isp", "train-proxy", "--out", out / "proxy", "--steps", "2", "--batch", "2", "--patch", "32"),
            *("--pool", "16", "--base", "4", "--json"),
        ],
        "isp train-software": [
            *("isp", "train-software", "--out", out / "sw", "--steps", "2", "--batch", "1", "--crop", "32"),
            *("--pool", "8", "--width", "4", "--depth", "1", "--val-every", "2", "--json"),
        ],
        "surrogate train": [
            *("surrogate", "train", tiny_data, "--out", out / "sur", "--steps", "2", "--batch", "8", "--hidden", "16"),
            *("--depth", "1", "--base-channels", "8", "--val-designs", "4", "--val-every", "2", "--json"),
        ],
        # (after its training: the dict's order is the run's)
        "surrogate eval": ["surrogate", "eval", out / "sur", tiny_data, "--out", out / "sur_eval"],
        "isp eval": [
            *("isp", "eval", "--size", "32", "--param-sets", "0", "--photo", "astronaut"),
            *("--out", out / "isp_eval"),
        ],
        "isp tune": ["isp", "tune", "--steps", "1", "--scenes", "2", "--size", "32", "--out", out / "tune"],
        "metrics": [
            "metrics",
            street / "images" / "street_0_000000.png",
            street / "images" / "street_0_000000.png",
            "--json",
        ],
    }


def test_every_torch_command_runs_with_device_cpu(optix, street, tiny_data, tmp_path):
    cmds = commands(street, tiny_data, tmp_path)
    for name, args in cmds.items():
        r = optix(*args, "--device", "cpu")
        assert r.returncode == 0, f"{name}: {r.stdout}{r.stderr}"
    results = json.loads((tmp_path / "design" / "results.json").read_text())
    assert results["device"] == "cpu"
    assert torch.load(tmp_path / "det" / "detector.pt", weights_only=True)["device"] == "cpu"
    r = optix("detect", "eval", tmp_path / "det", street, "--device", "cpu")
    assert r.returncode == 0 and json.loads(r.stdout)["device"] == "cpu", r.stdout + r.stderr
    assert json.loads((tmp_path / "proxy" / "train.json").read_text())["device"] == "cpu"
    assert json.loads((tmp_path / "sw" / "train.json").read_text())["device"] == "cpu"
    assert json.loads((tmp_path / "sur" / "train.json").read_text())["device"] == "cpu"
    assert json.loads((tmp_path / "sur_eval" / "eval.json").read_text())["device"] == "cpu"
    assert json.loads((tmp_path / "isp_eval" / "eval.json").read_text())["device"] == "cpu"
    assert json.loads((tmp_path / "tune" / "tune.json").read_text())["device"] == "cpu"


@pytest.mark.parametrize("spec", ["cuda", "cuda:1"])
def test_a_gpu_the_machine_lacks_is_one_error_naming_device(optix, street, tiny_data, tmp_path, monkeypatch, spec):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    cmds = commands(street, tiny_data, tmp_path)
    cmds["detect eval"] = ["detect", "eval", tmp_path / "nothing-yet", street]
    (tmp_path / "nothing-yet").mkdir()
    for name, args in cmds.items():
        r = optix(*args, "--device", spec)
        assert r.returncode == 1, f"{name}: {r.stdout}{r.stderr}"
        assert f"Error: --device {spec}: this machine has no CUDA device" in r.stderr, f"{name}: {r.stderr}"
        assert "Traceback" not in r.stderr, f"{name}: {r.stderr}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nothing-yet"]  # no folder was claimed


def test_a_device_that_is_no_device_lists_the_forms(optix, tmp_path):
    r = optix("design", "iq-software", "--out", tmp_path / "d", "--device", "gpu")
    assert r.returncode == 1 and "--device 'gpu': expected auto, cpu, cuda or cuda:K" in r.stderr, r.stderr
    assert not (tmp_path / "d").exists()
