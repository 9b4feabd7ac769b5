"""The detectors shipped inside the package (tasks/bundled/detectors.json): each file is the one
its manifest names, loads as a detector checkpoint, and is fp16; the detection task's defaults
start from the tuned one and its hardware ISP (issue 59)."""

from __future__ import annotations

import hashlib
import json

import pytest
import torch

from optix_e2e.camera_design.build import initial_isp_unit
from optix_e2e.camera_design.config import check_run_dir, load_config, make_config, resume_settings
from optix_e2e.camera_design.detection import load_start_detector
from optix_e2e.errors import InputError
from optix_e2e.tasks.detector_train import load_detector
from optix_e2e.tasks.shipped_detectors import BUNDLED, detector_file, is_shipped, shipped_detectors


def test_every_shipped_detector_is_the_file_its_manifest_names():
    shipped = shipped_detectors()
    assert {"street", "street-pretrained", "street-tuned"} <= set(shipped)
    for name, entry in shipped.items():
        path = BUNDLED / entry["file"]
        assert hashlib.sha256(path.read_bytes()).hexdigest() == entry["sha256"], name
        model, ck = load_detector(path)
        assert all(v.dtype == torch.float16 for v in ck["state_dict"].values() if v.is_floating_point()), name
        assert ck["step"] == entry["step"] and ("isp_unit" in ck) == entry["hardware_isp_tuned"], name
        assert entry["made_by"]
    assert shipped["street-pretrained"]["clean"]["map_50"] >= 0.92  # what issue 35 measured (eval_clean.json)
    assert detector_file("") == BUNDLED / "street_detector.pt"  # runs made before names: the first detector
    assert detector_file("runs/x/detector.pt").as_posix() == "runs/x/detector.pt"
    assert is_shipped("street-tuned") and not is_shipped("street-tuned.pt")


@pytest.mark.parametrize("budget", ["smoke", "quick", "full"])
def test_the_detection_defaults_start_from_the_tuned_detector_and_its_isp(budget):
    cfg = make_config(budget, task="detection", threads=1)
    assert (cfg.detector, cfg.isp_init, cfg.lens_steps) == ("street-tuned", "detector", "range")
    if budget != "smoke":
        return
    _, ck = load_detector(detector_file("street-tuned"))
    det = load_start_detector(cfg, cfg.crop_hw)
    for k, v in ck["state_dict"].items():  # the shipped fp16 weights, in a float32 detector
        assert torch.equal(det.state_dict()[k], v.float()), k
    assert torch.equal(initial_isp_unit(cfg), torch.tensor(ck["isp_unit"], dtype=torch.float32))
    # Alg. 1's random ISP start, as before, where asked for; the first detector has no tuned ISP
    assert not torch.equal(
        initial_isp_unit(make_config(budget, task="detection", isp_init="random")), initial_isp_unit(cfg)
    )
    with pytest.raises(InputError, match="no tuned ISP hyperparameters"):
        initial_isp_unit(make_config(budget, task="detection", detector="street-pretrained"))


def test_a_shipped_name_in_a_config_file_stays_a_name_and_a_wrong_one_is_refused(tmp_path):
    f = tmp_path / "d.toml"
    f.write_text('detector = "street-pretrained"\nisp_init = "random"\n')
    assert make_config("smoke", f, task="detection").detector == "street-pretrained"
    f.write_text('detector = "street-tunde"\n')
    with pytest.raises(InputError, match="detector: no such file .*street-tunde.*shipped detectors: street, "):
        make_config("smoke", f, task="detection")


def test_a_detection_run_made_on_the_first_detector_resumes_on_it(tmp_path):
    """A folder made before the tuned start was the default (detector "", isp_init random)
    resumes as it was made when the command gives neither."""
    made = make_config("smoke", task="detection", detector="", isp_init="random")
    check_run_dir(tmp_path / "run", made)
    today, given = load_config(None, task="detection")
    resumed = resume_settings(tmp_path / "run", today, given)
    assert (resumed.detector, resumed.isp_init) == ("", "random") and resumed.budget == "smoke"
    check_run_dir(tmp_path / "run", resumed)
    assert json.loads((tmp_path / "run" / "config.json").read_text())["detector"] == ""
