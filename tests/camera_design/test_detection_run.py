"""`optix design detection` end to end at the smoke budget: every output, the issue's keys in
results.json, the lens's f-number carried to the sensor, other settings refused, and a second
call that reuses the finished trainings and evaluations."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from optix_e2e.lens import Lens

pytestmark = pytest.mark.slow  # whole design runs


def test_smoke_detection_design_writes_every_output(tmp_path, optix, smoke_design):
    out = tmp_path / "run"
    r = optix(*smoke_design("detection", out))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "mAP@0.5" in r.stdout and "f-number" in r.stdout
    res = json.loads((out / "results.json").read_text())
    assert res["task"] == "detection" and res["optics_eval"] == "exact" and res["surrogate"] == "paper-triplet-detect"
    for who in ("nominal", "end_to_end"):
        c = res[who]
        for k in ("map_50", "map"):
            assert 0.0 <= c[k] <= 1.0 and 0.0 <= c["dark"][k] <= 1.0 and 0.0 <= c["surrogate"][k] <= 1.0
        assert 2.9 <= c["f_number"] <= 4.6
        # the exported lens has the f-number the surrogate's parameter says (EFL held)
        assert c["f_number_paraxial"] == pytest.approx(c["f_number"], rel=1e-3)
        assert len(c["rms_spot_um"]) == len(c["relative_illumination"]) == len(c["report_fields_deg"]) >= 3
        assert c["relative_illumination"][0] == pytest.approx(1.0, abs=1e-6)
    assert res["nominal"]["f_number"] == pytest.approx(4.4, abs=1e-3)
    for k in ("map_50", "map"):
        lo, hi = res["paired"][k]["ci95"]
        assert lo <= hi and lo - 1e-9 <= res["paired"][k]["mean"] <= hi + 1e-9
        assert "ci95" in res["paired"]["dark"][k]
    assert res["held_out"]["n_images"] == 4 and res["held_out"]["n_objects"] > 0
    assert set(res["isp_hyperparameters"]["end_to_end"]) == set(res["isp_hyperparameters"]["nominal"])
    for f in (
        "panels.png",
        "psf_nominal.png",
        "psf_end_to_end.png",
        "history.csv",
        "metrics.csv",
        "detections_end_to_end_exact.json",
        "report/end_to_end/layout.png",
        "report/nominal/spots.png",
    ):
        assert (out / f).is_file(), f
    assert any((out / "tb").iterdir())
    rows = list(csv.DictReader(open(out / "history.csv")))
    e2e = [r for r in rows if r["run"] == "end_to_end"]
    # Alg. 1 turns: optics, ISP, detector (2 steps each at smoke), then joint steps
    assert [r["block"] for r in e2e[:6]] == ["optics"] * 2 + ["isp"] * 2 + ["detector"] * 2
    assert all(float(r["classification"]) >= 0 for r in rows)
    # the nominal baseline: the same schedule without the lens, as many updates per processing block
    assert [r["block"] for r in rows if r["run"] == "nominal"] == ["isp"] * 2 + ["detector"] * 2 + ["all"] * 2
    t = res["training"]
    assert t["end_to_end"]["updates"] == {"optics": 4, "isp": 4, "detector": 4}
    assert t["nominal"]["updates"] == {"isp": 4, "detector": 4}
    z, j = Lens.load(out / res["lens_zmx"]), Lens.load(out / res["lens_json"])
    assert z.paraxial()["f_number"] == pytest.approx(j.paraxial()["f_number"], rel=1e-9)
    # other settings are refused; the same command reuses everything it finished
    r = optix(*smoke_design("detection", out, "--seed", "1"))
    assert r.returncode == 1 and "other settings" in r.stdout + r.stderr
    r = optix(*smoke_design("detection", out))
    assert r.returncode == 0, r.stdout + r.stderr
    again = json.loads((out / "results.json").read_text())
    assert again["paired"] == res["paired"] and again["end_to_end"]["map"] == res["end_to_end"]["map"]


def test_detection_needs_a_space_with_the_f_number(tmp_path, optix, smoke_design):
    r = optix(*smoke_design("detection", tmp_path / "r", "--surrogate", "paper-triplet-e2e"))
    assert r.returncode == 1 and "f_number" in r.stdout + r.stderr
    assert not (tmp_path / "r").exists()


def test_detection_in_the_wide_space_runs_on_exact_optics(tmp_path, optix, smoke_design):
    """The detection space with free centre thicknesses (issue 35) has no network: the run's
    lens steps go through the engine (its PSFs and one-pass gradient), the nominal
    baseline trains on the engine's PSFs of the nominal lens, and results.json says so; the
    surrogate's reference figures are absent, not made up."""
    (tmp_path / "wide.toml").write_text('optics = "exact"\nspace = "paper-triplet-detect-wide"\n')
    out = tmp_path / "run"
    r = optix(*smoke_design("detection", out, "--config", tmp_path / "wide.toml"))
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads((out / "results.json").read_text())
    m = res["optics_model"]
    assert m["mode"] == "exact" and m["network"] is False and "adds s_1_thickness, s_6_thickness" in m["no_network"]
    # 4 lens steps on the engine's one-pass gradient (P = 22, the f-number among them), none by
    # differences: no Jacobian's designs, no step choice
    e = m["engine"]
    assert e["gradient"] == "one-pass" and e["one_pass_gradients"] >= 4 and e["difference_fallbacks"] == 0
    assert e["designs"] < 20 and "steps" not in m
    assert res["design"]["parameters"][-3:] == ["s_1_thickness", "s_6_thickness", "f_number"]
    assert res["space"]["source"] == "paper-triplet-detect-wide" and not res["space"]["surrogates_own"]
    assert res["surrogate_psf_rel_l1_per_field"]["end_to_end"] is None
    for who in ("nominal", "end_to_end"):
        assert res[who]["surrogate"] is None and 0.0 <= res[who]["map_50"] <= 1.0
        assert res[who]["f_number_paraxial"] == pytest.approx(res[who]["f_number"], rel=1e-3)
    c = res["design"]["checks"]
    assert res["training"]["end_to_end"]["lens_steps"] == 4 and c["inside_space"] and c["manufacturable"]
    assert not list(out.glob("detections_*_surrogate.json"))
    # the lens moved in the new parameters too (their gradients come from the engine)
    i = res["design"]["parameters"].index("s_1_thickness")
    assert res["design"]["end_to_end"][i] != res["design"]["nominal"][i]
    # lens_steps = "range" (the detection default): Adam's first step, lr in u for every parameter
    # it moves, becomes lr / 4 of each range wherever the start sits. The f-number starts at 0.89
    # of its range, where the sigmoid alone gives 0.4 of that; the radii start mid-range
    names, scale = res["design"]["parameters"], res["design"]["step_scale"]
    assert scale[-1] == pytest.approx(1 / (4 * 0.8889 * 0.1111), rel=1e-3) and scale[0] == pytest.approx(1.0, abs=1e-3)
    path = list(csv.reader(open(out / "lens_path.csv")))
    assert path[2][1] == "optics" and path[2][2] == "0"  # the first lens step, not cut back
    span = np.array([np.subtract(*res["space"]["ranges"][n][::-1]) for n in names])
    moved = np.abs(np.array(path[2][3:], float) - np.array(path[1][3:], float)) / span
    lr = json.loads((out / "config.json").read_text())["lr_optics"]
    assert moved[-1] == pytest.approx(lr / 4, rel=0.03)  # 0.4 lr / 4 without the scale
    assert np.count_nonzero(moved > 0) >= 20 and moved.max() == pytest.approx(lr / 4, rel=0.03)
    # hybrid optics (a network refined along the run) is for the image-quality tasks
    (tmp_path / "hybrid.toml").write_text('optics = "hybrid"\n')
    r = optix(*smoke_design("detection", tmp_path / "h", "--config", tmp_path / "hybrid.toml"))
    assert r.returncode == 1 and "hybrid optics are for the image-quality tasks" in r.stdout + r.stderr


def test_the_start_detector_tuned_behind_the_nominal_camera_starts_a_design_run(tmp_path):
    """`optix detect tune` (camera_design/detector_tuning.py) at the smoke settings: the
    detector and the hardware ISP train behind the fixed nominal lens, the checkpoint loads as
    a design run's start detector and ISP, and a second call resumes with nothing to do."""
    import torch

    from optix_e2e.camera_design.config import make_config
    from optix_e2e.camera_design.detection import load_start_detector
    from optix_e2e.camera_design.detector_tuning import tune_start_detector
    from optix_e2e.tasks.detector_train import load_detector

    cfg = make_config("smoke", task="detection", threads=1).check()
    rec = tune_start_detector(cfg, tmp_path / "tune", 2, scenes=2, progress=False, log=lambda *_: None)
    assert rec["tuned_from"]["steps"] == 2 and rec["nominal_f_number"] == pytest.approx(4.4, abs=1e-3)
    for k in ("start", "tuned"):
        assert 0.0 <= rec[k]["map_50"] <= 1.0
    _, ck = load_detector(tmp_path / "tune" / "detector.pt")
    assert ck["step"] == 2 and ck["tuned"]["detector"] == "street_tuned.pt"  # the default start (shipped)
    tuned = load_start_detector(
        make_config("smoke", task="detection", detector=str(tmp_path / "tune" / "detector.pt")), cfg.crop_hw
    )
    bundled = load_start_detector(cfg, cfg.crop_hw)
    moved = [not torch.equal(a, b) for a, b in zip(tuned.state_dict().values(), bundled.state_dict().values())]
    assert any(moved)
    # the ISP trained from its default settings, and a run with isp_init = detector starts there
    from optix_e2e.camera_design.build import initial_isp_unit
    from optix_e2e.isp import params as hp

    start = torch.as_tensor(hp.to_unit(hp.defaults()), dtype=torch.float32)
    unit = torch.tensor(ck["isp_unit"])
    assert unit.shape == start.shape and not torch.allclose(unit, start, atol=1e-6)
    run_cfg = make_config(
        "smoke", task="detection", detector=str(tmp_path / "tune" / "detector.pt"), isp_init="detector"
    )
    assert torch.equal(initial_isp_unit(run_cfg.check()), unit)
    assert not torch.equal(initial_isp_unit(cfg), unit)  # the default: Alg. 1's random draw
    rows = (tmp_path / "tune" / "history.csv").read_text().splitlines()
    assert len(rows) == 3  # the header and two steps
    again = tune_start_detector(cfg, tmp_path / "tune", 2, scenes=2, progress=False, log=lambda *_: None)
    assert again["start"] == rec["start"] and (tmp_path / "tune" / "history.csv").read_text().splitlines() == rows
    # other settings in the same folder, or a folder of something else: refused, nothing written
    with pytest.raises(ValueError, match=r"tuned with other settings \(steps: 2 -> 3\)"):
        tune_start_detector(cfg, tmp_path / "tune", 3, scenes=2, progress=False, log=lambda *_: None)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds no detector tuning"):
        tune_start_detector(cfg, tmp_path / "other", 2, scenes=0, progress=False, log=lambda *_: None)
    assert [p.name for p in (tmp_path / "other").iterdir()] == ["notes.txt"]


def test_isp_init_from_the_detector_is_refused_where_it_cannot_hold(tmp_path):
    from optix_e2e.camera_design.config import make_config

    with pytest.raises(ValueError, match="isp_init must be random or detector"):
        make_config("smoke", task="detection", isp_init="tuned").check()
    with pytest.raises(ValueError, match="needs the detection task and a tuned checkpoint"):
        make_config("smoke", task="detection", detector="", isp_init="detector").check()  # the first holds no ISP
    (tmp_path / "d.pt").write_bytes(b"")
    with pytest.raises(ValueError, match="needs the detection task"):
        make_config("smoke", task="iq-hardware", isp_init="detector", detector=str(tmp_path / "d.pt")).check()
