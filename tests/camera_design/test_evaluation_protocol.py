"""The evaluation protocol fixed before the result is known (issue 34): the frame, the centre and
the corner each paired apart with the frame the headline, the same number of processing updates
for both cameras, and an evaluation cache keyed on everything that decides a figure."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch
from torch import nn

from optix_e2e.camera_design import eval_cache
from optix_e2e.camera_design import evaluate as ev
from optix_e2e.camera_design.build import make_optimizer
from optix_e2e.camera_design.config import DesignConfig, check_run_dir, load_config, make_config, resume_settings
from optix_e2e.tasks.samples import POSITIONS

pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ----- positions: the frame the headline, centre and corner beside it ----------------------------
def _rows(shift: float) -> list[dict]:
    """Three images at the default positions; psnr = 30 + image + shift (more at the corner)."""
    rows = []
    for i in range(3):
        for j, pos in enumerate(POSITIONS[DesignConfig().eval_positions]):
            extra = {"frame": 0.1 * j, "centre": 0.0, "corner": 2.0 * shift}[pos]
            r = {"image": f"img{i}", "position": pos, "radius": 0.2 if pos != "corner" else 0.97}
            r.update({"psnr_db": 30.0 + i + shift + extra, "ssim": 0.9, "lpips": 0.2, "haarpsi": 0.8})
            rows.append(r)
    return rows


def test_the_default_evaluation_holds_frame_centre_and_corner_with_the_frame_the_headline():
    assert POSITIONS[DesignConfig().eval_positions] == ("frame",) * 4 + ("centre", "corner")
    assert POSITIONS["frame"] == ("frame",) * 4 and POSITIONS["centre-corner"] == ("centre", "corner")
    a, b = _rows(0.0), _rows(1.0)
    by = ev.paired_by_position(a, b, 200, 0)
    assert list(by) == ["frame", "centre", "corner"]
    frame_only = ev.paired(ev.at_position(a, "frame"), ev.at_position(b, "frame"), 200, 0)
    assert ev.paired(a, b, 200, 0) == by["frame"] == frame_only  # the headline: frame samples alone
    assert by["frame"]["psnr_db"]["mean"] == pytest.approx(1.0) and by["corner"]["psnr_db"]["mean"] == pytest.approx(
        3.0
    )
    for p in by.values():
        assert {"mean", "ci95"} <= set(p["psnr_db"]) and p["psnr_db"]["n_images"] == 3
    s = ev.summarize(b)  # the camera's means: the frame samples; every position beside them
    assert s["n_samples"] == 12 and s["psnr_db"] == pytest.approx(32.15)
    assert set(s["by_position"]) == {"frame", "centre", "corner"} and s["by_position"]["corner"]["psnr_db"] == 34.0
    assert ev.headline_position(a) == "frame" and ev.headline_position(ev.at_position(a, "corner")) == "all"
    # an evaluation without frame samples is paired over all of them, as before
    cc_a, cc_b = [r for r in a if r["position"] != "frame"], [r for r in b if r["position"] != "frame"]
    assert ev.paired(cc_a, cc_b, 200, 0)["psnr_db"]["mean"] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="same held-out images"):
        ev.paired(a, [r for r in b if r["position"] != "centre"] + ev.at_position(b, "frame")[:1], 200, 0)


def _summary_results(untuned_shift: float) -> dict:
    """results.json's image-quality entries for three images: nominal +0, end-to-end +1, the
    untuned baseline +untuned_shift, the ideal lens +4 dB (summarize as ImageQualityHooks does)."""
    from optix_e2e.camera_design.image_quality import headline_baseline

    rows = {"nominal": _rows(0.0), "end_to_end": _rows(1.0), "nominal_untuned": _rows(untuned_shift)}
    rows["ideal_lens"] = _rows(4.0)
    res = {who: ev.summarize(r) for who, r in rows.items()}
    res["paired_against"] = {}
    for who in ("nominal", "nominal_untuned", "ideal_lens"):
        by = ev.paired_by_position(rows[who], rows["end_to_end"], 200, 0)
        res["paired_against"][who] = {"paired": by["frame"], "paired_by_position": by}
    base = headline_baseline(res)
    res.update(
        baseline={**base, "paired": res["paired_against"][base["camera"]]["paired"]},
        paired=res["paired_against"]["nominal"]["paired"],
        paired_by_position=res["paired_against"]["nominal"]["paired_by_position"],
        headline_position="frame",
        held_out={"n_images": 3, "per_image": 6, "per_image_by_position": {"frame": 4, "centre": 1, "corner": 1}},
        optics_model={
            "mode": "surrogate",
            "choice": {"why": "x"},
            "final_error_per_field": [0.01],
            "final_network_error_per_field": [0.01],
            "n_refinements": 0,
            "exact_gradient_steps": 0,
        },
    )
    return res


def test_the_headline_baseline_is_the_better_of_the_fine_tuned_and_the_untuned_processing():
    from optix_e2e.camera_design.image_quality import headline_baseline

    def means(n, u):
        return {"nominal": {"psnr_db": n}, "nominal_untuned": {"psnr_db": u}}

    got = headline_baseline(means(25.6, 26.4))
    assert got["camera"] == "nominal_untuned" and got["psnr_db"] == {"nominal": 25.6, "nominal_untuned": 26.4}
    assert "26.4000 dB > nominal 25.6000 dB" in got["why"] and "lowered" in got["why"]
    assert headline_baseline(means(26.4, 25.6))["camera"] == "nominal"
    assert headline_baseline(means(25.6, 25.6))["camera"] == "nominal"  # a tie: the paper's fair comparison


@pytest.mark.parametrize("untuned_shift", [-0.5, 0.5])
def test_summary_lines_give_the_headline_against_the_better_baseline_and_the_centre_and_corner(untuned_shift):
    from optix_e2e.camera_design.image_quality import ImageQualityHooks

    res = _summary_results(untuned_shift)
    name = "nominal_untuned" if untuned_shift > 0 else "nominal"
    assert res["baseline"]["camera"] == name
    lines = ImageQualityHooks.summary_lines(res)
    assert "headline: 4 frame positions per image" in lines[0]
    assert lines[1].strip().startswith(f"headline baseline: {name} (") and f"minus {name}" in lines[1]
    # the headline diff is end-to-end minus the chosen baseline; the other comparisons beside it
    want = 1.0 - max(untuned_shift, 0.0)
    assert any(line.strip().startswith("PSNR dB") and f"diff {want:+.4f}" in line for line in lines), lines
    other = "nominal" if name == "nominal_untuned" else "nominal_untuned"
    assert any(
        f"end-to-end minus {other} {1.0 - (untuned_shift if other != 'nominal' else 0):+.4f}" in x for x in lines
    )
    ideal = [line for line in lines if "end-to-end minus ideal_lens -3.0000" in line]
    assert len(ideal) == 1 and "ceiling" in ideal[0]
    centre = [line for line in lines if line.strip().startswith("centre")]
    corner = [line for line in lines if line.strip().startswith("corner")]
    # the corner: end-to-end +3 over nominal (_rows), so +3 - 3 * shift over the untuned (its corner moves 3x)
    at_corner = 3.0 if name == "nominal" else 3.0 - 3 * untuned_shift
    assert len(centre) == len(corner) == 1 and f"diff {at_corner:+.4f} [" in corner[0] and name in corner[0]


def test_an_old_run_made_with_frame_positions_resumes_with_them(tmp_path):
    old = make_config("smoke", eval_positions="frame")
    check_run_dir(tmp_path / "run", old)
    today, given = load_config("smoke")
    assert today.eval_positions == "frame+centre+corner"
    with pytest.raises(ValueError, match="other settings.*eval_positions"):
        check_run_dir(tmp_path / "run", today)
    kept = resume_settings(tmp_path / "run", today, given)
    assert kept == old
    check_run_dir(tmp_path / "run", kept)  # accepted: the run resumes as it was made
    # a new folder, or one made with today's default, is left alone; a choice given is held to the folder
    assert resume_settings(tmp_path / "new", today, given) == today
    check_run_dir(tmp_path / "today", today)
    assert resume_settings(tmp_path / "today", today, given) == today
    cc, given = load_config("smoke", eval_positions="centre-corner")
    assert resume_settings(tmp_path / "run", cc, given) == cc


# ----- the same number of processing updates for both cameras ------------------------------------
class _Camera:
    """A stand-in camera: one small parameter vector per block, on the CPU."""

    device = torch.device("cpu")

    def __init__(self, names):
        self.params = {n: [nn.Parameter(torch.linspace(0.1, 0.9, 3) * (i + 1))] for i, n in enumerate(names)}

    def blocks(self):
        return dict(self.params)


def _count_updates(cam: _Camera, opt) -> dict[str, int]:
    """Run ``opt`` to its end; how many steps changed each block's parameters."""
    n = {k: 0 for k in cam.params}
    for _ in range(opt.total_steps):
        before = {k: [p.detach().clone() for p in ps] for k, ps in cam.params.items()}
        opt.step(lambda: sum(((p - 3.0) ** 2).sum() for ps in cam.params.values() for p in ps))
        for k, ps in cam.params.items():
            n[k] += int(any(not torch.equal(p.detach(), q) for p, q in zip(ps, before[k])))
    return n


@pytest.mark.parametrize("task", ["iq-software", "iq-hardware", "detection"])
@pytest.mark.parametrize("optimizer", ["alg1", "vanilla"])
def test_the_baseline_gets_as_many_updates_per_processing_block_as_the_end_to_end_camera(task, optimizer):
    cfg = make_config("smoke", task=task, optimizer=optimizer, steps_isp=3, n_finetune=2)
    processing = ["isp", "detector"] if task == "detection" else ["isp"]
    e2e_cam, nom_cam = _Camera(["optics", *processing]), _Camera(processing)  # the nominal's lens is fixed
    e2e, nom = make_optimizer(cfg, e2e_cam, optimizer), make_optimizer(cfg, nom_cam, "nominal")
    assert nom.kind == e2e.kind == optimizer
    got_e2e, got_nom = _count_updates(e2e_cam, e2e), _count_updates(nom_cam, nom)
    assert got_nom == {k: got_e2e[k] for k in processing}
    want = cfg.total_steps if optimizer == "vanilla" else cfg.n_cycles * 3 + cfg.n_finetune
    assert got_nom["isp"] == want
    # what results.json records (the optimizers' own counts) is what they did, and what they planned
    assert e2e.updates() == got_e2e == e2e.scheduled_updates()
    assert nom.updates() == got_nom == nom.scheduled_updates()


def test_a_baseline_checkpoint_of_the_old_schedule_is_refused_with_a_reason(tmp_path):
    from optix_e2e.camera_design.alg1 import Block, ProximalCompositional
    from optix_e2e.camera_design.training import _load_state, _save_state

    cfg = make_config("smoke")
    w = nn.Linear(2, 1)
    # before 2026-11-27: total_steps joint steps on the processing (1-step blocks, no cycle)
    old = ProximalCompositional([Block("isp", list(w.parameters()), 1e-3)], n_cycles=0, n_finetune=cfg.total_steps)
    hist = []
    for _ in range(3):
        hist.append({"block": old.step(lambda: w(torch.ones(1, 2)).sum())["block"]})
    path = tmp_path / "nominal_state.pt"
    _save_state(path, w, old, 1.0, hist)
    cam = _Camera(["isp"])
    cam.params["isp"] = list(w.parameters())
    new = make_optimizer(cfg, cam, "nominal")
    with pytest.raises(ValueError, match="another schedule.*step 1 updated 'all'.*'isp'") as err:
        _load_state(path, w, new)
    assert str(path) in str(err.value) and "damaged" not in str(err.value)
    # the whole old schedule (more steps than the new one has) is refused the same way
    for _ in range(cfg.total_steps - 3):
        hist.append({"block": old.step(lambda: w(torch.ones(1, 2)).sum())["block"]})
    _save_state(path, w, old, 1.0, hist)
    with pytest.raises(ValueError, match="another schedule"):
        _load_state(path, w, make_optimizer(cfg, cam, "nominal"))
    # a checkpoint of this schedule resumes
    again = make_optimizer(cfg, cam, "nominal")
    hist = [{"block": again.step(lambda: w(torch.ones(1, 2)).sum())["block"]} for _ in range(3)]
    _save_state(path, w, again, 1.0, hist)
    resumed = make_optimizer(cfg, cam, "nominal")
    assert _load_state(path, w, resumed)[1] == hist and resumed.t == 3


# ----- the evaluation cache's key -------------------------------------------------------------------
def test_the_eval_cache_key_holds_the_samples_the_sensor_and_the_code(monkeypatch):
    from optix_e2e.camera import SensorStage, calibrated_preset
    from optix_e2e.camera_design.image_quality import _camera_key
    from optix_e2e.tasks import heldout_set

    samples = heldout_set(16, 2, 1, photos=[], positions=("frame", "centre"))
    psf, vig, fh = torch.rand(2, 3, 5, 5), torch.rand(2, 3), torch.tensor([0.0, 1.0])
    isp, sensor = nn.Linear(3, 3), SensorStage(calibrated_preset("imx249", 4.4))

    def key(samples=samples, sensor=sensor, isp=isp):
        return _camera_key(psf, vig, fh, isp, sensor, samples, eval_cache.samples_digest(samples))

    base = key()
    assert key() == base  # the same inputs, rebuilt: the same key
    assert key(samples=heldout_set(16, 2, 1, photos=[], positions=("frame", "centre"))) == base
    assert key(sensor=SensorStage(calibrated_preset("imx249", 4.4))) == base
    # the held-out samples: each field that decides a figure
    s0 = samples[0]
    for change in (
        dict(scene=s0.scene + 1e-3),
        dict(target=s0.target * 0.5),
        dict(offset_px=(s0.offset_px[0] + 2, s0.offset_px[1])),
        dict(position="corner"),
        dict(noise_seed=s0.noise_seed + 1),
    ):
        assert key(samples=[dataclasses.replace(s0, **change), *samples[1:]]) != base, change
    assert key(samples=samples[:1]) != base
    # the sensor: its preset, its noise, another task's exposure
    assert key(sensor=SensorStage(calibrated_preset("imx249", 2.8))) != base
    assert key(sensor=SensorStage(calibrated_preset("imx249", 4.4), noise=False)) != base
    assert key(sensor=SensorStage(calibrated_preset("imx249", 4.4, 0.01, 100.0))) != base
    # the processing, as before
    other = nn.Linear(3, 3)
    assert key(isp=other) != base
    # the code: a change to any source file (here, its digest) evaluates again
    code = eval_cache.code_digest()
    assert code == eval_cache.code_digest() and len(code) == 64
    monkeypatch.setattr(eval_cache, "code_digest", lambda: "0" * 64)
    assert key() != base


def test_a_cached_evaluation_is_reused_only_under_its_own_key(tmp_path):
    from optix_e2e.camera_design.image_quality import read_eval_cache

    row = {"image": "photo:a", "position": "frame", "radius": 0.3, "psnr_db": 25.0, "ssim": 0.8}
    row.update(lpips=0.1, haarpsi=0.7)
    path = tmp_path / "eval_nominal_exact.json"
    eval_cache.write(path, "k1", 1.0, rows=[row])
    assert read_eval_cache(path, "k1")["rows"] == [row] and read_eval_cache(path, "k2") is None
    assert json.loads(path.read_text())["key"] == "k1"
