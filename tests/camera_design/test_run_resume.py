"""`optix design` end to end: a seconds-long run writes every output file, refuses other
settings, resumes after kill -9 on the same path, and exports a lens that reloads."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from optix_e2e.lens import Lens

pytestmark = pytest.mark.slow  # whole design runs


N_STEPS = 14  # n_cycles 3: 3 x (2 + 2) + 2 steps, a checkpoint after each


@pytest.fixture(scope="module")
def killed_run(tmp_path_factory, smoke_design):
    """A smoke run (its own process) killed with SIGKILL once its first checkpoint is on disk;
    what it left."""
    tmp = tmp_path_factory.mktemp("design")
    out, cfg = tmp / "run", tmp / "c.toml"
    cfg.write_text("n_cycles = 3\ncheckpoint_every = 1\n")
    cmd = [sys.executable, "-m", "optix_e2e", *smoke_design("iq-software", out, "--config", cfg)]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    state = out / "end_to_end_state.pt"
    deadline = time.time() + 240
    while not state.is_file() and time.time() < deadline and p.poll() is None:
        time.sleep(0.05)
    assert p.poll() is None, p.stdout.read().decode()
    assert state.is_file(), "no checkpoint within the deadline"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    from optix_e2e.torchfile import load_plain

    return {"tmp": tmp, "out": out, "cfg": cfg, "state": load_plain(state, "design checkpoint")}


@pytest.fixture(scope="module")
def resumed_run(killed_run, optix, smoke_design):
    """The same command again (in this process): it resumes and finishes (stdout, results)."""
    out = killed_run["out"]
    r = optix(*smoke_design("iq-software", out, "--config", killed_run["cfg"]))
    assert r.returncode == 0, r.stdout + r.stderr
    return {**killed_run, "stdout": r.stdout, "res": json.loads((out / "results.json").read_text())}


def test_kill_9_leaves_a_checkpoint_and_no_results(killed_run):
    t_kill = int(killed_run["state"]["optimizer"]["t"])
    assert 1 <= t_kill < N_STEPS and len(killed_run["state"]["history"]) == t_kill
    assert not (killed_run["out"] / "results.json").exists()


def test_other_settings_are_refused_in_a_killed_runs_folder(killed_run, optix, smoke_design):
    out, cfg = killed_run["out"], killed_run["cfg"]
    r = optix(*smoke_design("iq-software", out, "--config", cfg, "--seed", "1"))
    assert r.returncode == 1 and "other settings" in r.stdout + r.stderr and "seed" in r.stdout + r.stderr


def test_the_same_command_resumes_at_the_killed_step_and_runs_each_step_once(resumed_run):
    before = resumed_run["state"]
    t_kill = int(before["optimizer"]["t"])
    assert f"end_to_end: resuming at step {t_kill} of {N_STEPS}" in resumed_run["stdout"], resumed_run["stdout"]
    rows = [r for r in csv.DictReader(open(resumed_run["out"] / "history.csv")) if r["run"] == "end_to_end"]
    assert [int(r["step"]) for r in rows] == list(range(1, N_STEPS + 1))
    # the steps before the kill were not run again (a restart would re-time them)
    assert [float(r["seconds"]) for r in rows[:t_kill]] == [h["seconds"] for h in before["history"]]


def test_results_hold_every_figure_under_exact_optics(resumed_run):
    res = resumed_run["res"]
    for k in ("task", "optics_eval", "nominal", "end_to_end", "paired", "lens_zmx", "wall_s"):
        assert k in res, k
    assert res["optics_eval"] == "exact" and res["task"] == "iq-software"
    for who in ("nominal", "end_to_end"):
        for m in ("psnr_db", "ssim", "lpips", "haarpsi"):
            assert isinstance(res[who][m], float) and isinstance(res[who]["surrogate"][m], float)
    # the further cameras (issue 54): the same keys as the nominal's, on the same samples, printed;
    # the perfect lens behind the nominal's processing (no ceiling) is gone
    for who, what in (("nominal_untuned", "processing"), ("ideal_lens", "lens")):
        assert set(res[who]) == set(res["nominal"]) - {"surrogate"} | {what}, who
        assert res[who]["n_samples"] == res["nominal"]["n_samples"] and f"{who} " in resumed_run["stdout"]
    assert "perfect_lens" not in res and not (resumed_run["out"] / "eval_perfect_lens_exact.json").exists()
    # the ceiling is one: processing fine-tuned behind a lens that blurs nothing beats the nominal camera
    assert res["ideal_lens"]["psnr_db"] > max(res["nominal"]["psnr_db"], res["nominal_untuned"]["psnr_db"])
    for m in ("psnr_db", "ssim", "lpips", "haarpsi"):
        lo, hi = res["paired"][m]["ci95"]
        assert lo <= res["paired"][m]["mean"] <= hi
    win = res["exact_psf_energy_in_window"]
    for who in ("nominal", "end_to_end"):
        assert len(win[who]) == len(win["fields_deg"]) and all(0.5 < e <= 1.01 for e in win[who]), win
        assert res["exact_psf_method"][who] == "auto"  # the surrogate's dataset's method (no fallback)


def test_results_pair_frame_centre_and_corner_apart_the_frame_the_headline(resumed_run):
    # issue 34: each held-out image at the frame's 4 positions, the centre and the corner; the
    # headline (``paired``) is the frame's comparison, stated once with its reason
    res, out = resumed_run["res"], resumed_run["out"]
    assert res["held_out"]["positions"] == "frame+centre+corner" and res["held_out"]["per_image"] == 6
    assert res["held_out"]["per_image_by_position"] == {"frame": 4, "centre": 1, "corner": 1}
    by = res["paired_by_position"]
    assert list(by) == ["frame", "centre", "corner"]
    for p in by.values():
        for m in ("psnr_db", "ssim", "lpips", "haarpsi"):
            lo, hi = p[m]["ci95"]
            assert lo - 1e-9 <= p[m]["mean"] <= hi + 1e-9 and p[m]["n_images"] == res["held_out"]["n_images"]
    assert res["paired"] == by["frame"]
    assert res["headline_position"] == res["held_out"]["headline_position"] == "frame"
    assert (
        res["headline_position_why"].startswith("frame: 4 stratified uniform positions")
        and "issue 34" in (res["headline_position_why"])
    )
    # the cameras' means are the frame samples'; every position is beside them
    rows = [r for r in csv.DictReader(open(out / "metrics.csv")) if r["optics"] == "exact"]
    frame = [float(r["psnr_db"]) for r in rows if r["camera"] == "nominal" and r["position"] == "frame"]
    assert res["nominal"]["psnr_db"] == pytest.approx(sum(frame) / len(frame), rel=1e-12)
    assert res["nominal"]["n_samples"] == 4 * res["held_out"]["n_images"]
    assert set(res["nominal"]["by_position"]) == {"frame", "centre", "corner"}
    # what the run prints: the frame headline, then a line each for the centre and the corner,
    # against the headline baseline
    stdout = resumed_run["stdout"]
    assert "headline: 4 frame positions per image" in stdout
    by_base = res["paired_against"][res["baseline"]["camera"]]["paired_by_position"]
    for pos in ("centre", "corner"):
        lo, hi = by_base[pos]["psnr_db"]["ci95"]
        assert f"diff {by_base[pos]['psnr_db']['mean']:+.4f} [{lo:+.4f}, {hi:+.4f}]" in stdout, pos


def test_both_cameras_get_as_many_updates_per_processing_block(resumed_run):
    # n_cycles 3 of (2 optics + 2 ISP steps) then 2 joint steps: every block 3 x 2 + 2 = 8 updates,
    # counted by the optimizers across the kill and the resume
    t = resumed_run["res"]["training"]
    assert t["end_to_end"]["updates"] == {"optics": 8, "isp": 8}
    assert t["nominal"]["updates"] == {"isp": 8} and t["nominal"]["steps"] == 3 * 2 + 2
    assert "the end-to-end run's updates per processing block (isp 8)" in resumed_run["stdout"]


def test_the_headline_baseline_is_the_better_of_nominal_and_nominal_untuned(resumed_run):
    # issue 54: end-to-end against the better of the two baselines by mean headline PSNR, said
    # why; the paired comparison against each baseline and against the ideal lens
    res, stdout = resumed_run["res"], resumed_run["stdout"]
    base, against = res["baseline"], res["paired_against"]
    n, u = res["nominal"]["psnr_db"], res["nominal_untuned"]["psnr_db"]
    assert base["camera"] == ("nominal_untuned" if u > n else "nominal")
    assert base["psnr_db"] == {"nominal": n, "nominal_untuned": u} and base["why"] and base["rule"]
    assert f"headline baseline: {base['camera']} (" in stdout
    assert list(against) == ["nominal", "nominal_untuned", "ideal_lens"]
    assert base["paired"] == against[base["camera"]]["paired"]
    # against the fine-tuned nominal: the run's ``paired`` (unchanged since before issue 54)
    assert against["nominal"] == {"paired": res["paired"], "paired_by_position": res["paired_by_position"]}
    rows = list(csv.DictReader(open(resumed_run["out"] / "metrics.csv")))
    for who, kind in (("nominal_untuned", "exact"), ("ideal_lens", "delta")):
        pa = against[who]
        assert list(pa["paired_by_position"]) == ["frame", "centre", "corner"]
        assert pa["paired"] == pa["paired_by_position"]["frame"]
        # end-to-end minus that camera: the difference of the two cameras' frame means
        d = res["end_to_end"]["psnr_db"] - res[who]["psnr_db"]
        assert pa["paired"]["psnr_db"]["mean"] == pytest.approx(d, abs=1e-9)
        assert len([r for r in rows if r["camera"] == who and r["optics"] == kind]) == res["held_out"]["n_samples"]
    d = against["ideal_lens"]["paired"]["psnr_db"]
    assert f"end-to-end minus ideal_lens {d['mean']:+.4f}" in stdout


def test_nominal_untuned_is_the_untouched_start_isp_behind_the_nominal_lens(resumed_run):
    """An independent evaluation: the shipped software ISP as loaded, the nominal lens's exact
    PSFs from the engine, the held-out set rebuilt: the run's nominal_untuned rows, number for number."""
    import numpy as np
    import torch

    from optix_e2e.camera import Camera, FixedOptics, SensorStage, SoftwareISPStage, calibrated_preset
    from optix_e2e.camera_design import evaluate as ev
    from optix_e2e.camera_design.build import SOFTWARE_ISP, base_lens_f_number, design_field_heights, load_surrogate
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.isp.software import SoftwareISP
    from optix_e2e.surrogate.ground_truth import exact_optics
    from optix_e2e.tasks import SensorFrame, heldout_set
    from optix_e2e.tasks.samples import POSITIONS

    res, out = resumed_run["res"], resumed_run["out"]
    cfg = make_config("smoke", resumed_run["cfg"])
    sur, frame = load_surrogate(cfg.surrogate), SensorFrame()
    nominal = np.asarray(res["design"]["nominal"], np.float64)
    exact = exact_optics(sur, nominal[None])
    heights = design_field_heights(sur, nominal, float(exact["image_distance"][0]))
    optics = FixedOptics(
        exact["psf"][0], exact["vignetting"][0], heights, patch=cfg.patch, full_field_px=frame.full_field_px
    )
    preset = calibrated_preset("imx249", base_lens_f_number(sur))
    camera = Camera(optics, SensorStage(preset), SoftwareISPStage(SoftwareISP.load(SOFTWARE_ISP), preset))
    samples = heldout_set(
        cfg.eval_size,
        exact["psf"].shape[-1] // 2,
        cfg.eval_procedural,
        cfg.eval_level,
        frame,
        positions=POSITIONS[cfg.eval_positions],
    )
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the run (--threads 1)
    try:
        want = ev.evaluate(camera, samples)
    finally:
        torch.set_num_threads(threads)
    got = [r for r in csv.DictReader(open(out / "metrics.csv")) if r["camera"] == "nominal_untuned"]
    assert [(r["image"], r["position"]) for r in got] == [(w["image"], w["position"]) for w in want]
    for r, w in zip(got, want):
        for m in ev.METRICS:
            assert float(r[m]) == pytest.approx(w[m], rel=1e-6, abs=1e-9), (r["image"], m)
    assert res["nominal_untuned"]["psnr_db"] == pytest.approx(ev.summarize(want)["psnr_db"], rel=1e-6)
    # and it is not the fine-tuned baseline's processing
    nominal_rows = [r for r in csv.DictReader(open(out / "metrics.csv")) if r["camera"] == "nominal"]
    assert any(float(a["psnr_db"]) != float(b["psnr_db"]) for a, b in zip(nominal_rows, got))


def test_the_ideal_lens_trains_on_the_nominals_budget_with_its_own_checkpoint(resumed_run):
    res, out = resumed_run["res"], resumed_run["out"]
    t = res["training"]
    assert t["ideal_lens"]["updates"] == t["nominal"]["updates"] == {"isp": 8}
    assert t["ideal_lens"]["steps"] == t["nominal"]["steps"] and t["ideal_lens"]["lens_steps"] == 0
    from optix_e2e.torchfile import load_plain

    state = load_plain(out / "ideal_lens_state.pt", "design checkpoint")
    assert state["optimizer"]["t"] == t["ideal_lens"]["steps"]
    psf = state["camera"]["optics.psf"]  # a one-pixel PSF at every field and channel
    c = psf.shape[-1] // 2
    assert bool((psf[..., c, c] == 1).all()) and float(psf.sum()) == psf.shape[0] * psf.shape[1]
    rows = [r for r in csv.DictReader(open(out / "history.csv")) if r["run"] == "ideal_lens"]
    assert [int(r["step"]) for r in rows] == list(range(1, t["ideal_lens"]["steps"] + 1))


class _Stop(Exception):
    """Stands for a kill in the middle of the ideal lens's training."""


def test_a_run_finished_before_the_ideal_lens_existed_fills_in_the_new_entries(
    resumed_run, tmp_path, optix, smoke_design, monkeypatch
):
    """A finished run folder from before issue 54 (no ideal_lens checkpoint, no untuned or
    ideal evaluation): the same command trains the ideal lens (stopped half-way, it resumes at
    its last checkpoint) and computes the new entries, the figures of a run made with them."""
    import shutil

    from optix_e2e.camera_design import run as run_module
    from optix_e2e.torchfile import load_plain

    res, old = resumed_run["res"], tmp_path / "old"
    shutil.copytree(resumed_run["out"], old)
    for f in ("ideal_lens_state.pt", "eval_ideal_lens_delta.json", "eval_nominal_untuned_exact.json"):
        (old / f).unlink()
    new_keys = ("nominal_untuned", "ideal_lens", "paired_against", "baseline")
    before = {k: v for k, v in res.items() if k not in new_keys}
    before["training"] = {k: v for k, v in res["training"].items() if k != "ideal_lens"}
    (old / "results.json").write_text(json.dumps(before))
    train = run_module.train

    def stopped(*args, **kw):
        if args[4] == "ideal_lens":

            def stop(info, camera):
                if info["step"] == 3:
                    raise _Stop

            kw["on_step"] = stop
        return train(*args, **kw)

    monkeypatch.setattr(run_module, "train", stopped)
    args = smoke_design("iq-software", old, "--config", resumed_run["cfg"])
    r = optix(*args)
    assert r.returncode != 0 and "_Stop" in r.stderr
    assert load_plain(old / "ideal_lens_state.pt", "design checkpoint")["optimizer"]["t"] == 2
    monkeypatch.setattr(run_module, "train", train)
    r = optix(*args)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"end_to_end: resuming at step {N_STEPS} of {N_STEPS}" in r.stdout
    assert "ideal_lens: resuming at step 2 of 8" in r.stdout
    again = json.loads((old / "results.json").read_text())
    for k in new_keys:
        assert again[k] == res[k], k
    assert again["training"]["ideal_lens"]["updates"] == res["training"]["ideal_lens"]["updates"]


def test_every_output_file_is_written(resumed_run):
    out = resumed_run["out"]
    for f in (
        "panels.png",
        "psf_nominal.png",
        "psf_end_to_end.png",
        "history.csv",
        "metrics.csv",
        "report/end_to_end/layout.png",
        "report/end_to_end/mtf.png",
        "report/nominal/spots.png",
    ):
        assert (out / f).is_file(), f
    assert any((out / "tb").iterdir())


def test_the_lens_path_holds_every_lens_step_across_the_kill(resumed_run):
    res, out = resumed_run["res"], resumed_run["out"]
    names = res["design"]["parameters"]
    rows = list(csv.DictReader(open(out / "lens_path.csv")))
    # step 0 (the start), then the 8 lens steps (3 cycles x 2 optics steps + 2 joint steps)
    assert [int(r["step"]) for r in rows] == [0, 1, 2, 5, 6, 9, 10, 13, 14]
    assert [r["block"] for r in rows] == ["start"] + ["optics"] * 6 + ["all"] * 2
    assert [float(rows[0][n]) for n in names] == pytest.approx(res["design"]["start"], rel=1e-6)
    assert [float(rows[-1][n]) for n in names] == pytest.approx(res["design"]["end_to_end"], rel=1e-6)
    travel = res["design"]["travel"]
    assert travel["lens_steps_recorded"] == res["training"]["end_to_end"]["lens_steps"] == 8
    lo_hi = res["space"]["ranges"]
    moved = [abs(float(rows[-1][n]) - float(rows[0][n])) / (lo_hi[n][1] - lo_hi[n][0]) for n in names]
    assert travel["largest_final"] == pytest.approx(max(moved), rel=1e-4) and travel["largest_final"] > 0
    assert travel["largest_farthest"] >= travel["largest_final"]


def test_the_exported_lens_reloads_to_the_same_design(resumed_run):
    res, out = resumed_run["res"], resumed_run["out"]
    z, j = Lens.load(out / res["lens_zmx"]), Lens.load(out / res["lens_json"])
    assert z.paraxial()["efl_mm"] == pytest.approx(j.paraxial()["efl_mm"], rel=1e-9)
    for f in (0.0, 14.9):
        assert z.spot(f)["rms_um"] == pytest.approx(j.spot(f)["rms_um"], rel=1e-6)
    checks = res["design"]["checks"]
    assert checks["inside_space"] and checks["manufacturable"] and checks["refocused"], checks


def test_an_uninterrupted_run_lands_on_the_same_lens(resumed_run, optix, smoke_design):
    tmp, res = resumed_run["tmp"], resumed_run["res"]
    r = optix(*smoke_design("iq-software", tmp / "again", "--config", resumed_run["cfg"]))
    assert r.returncode == 0, r.stdout + r.stderr
    again = json.loads((tmp / "again" / "results.json").read_text())
    assert again["design"]["end_to_end"] == res["design"]["end_to_end"]
    assert again["end_to_end"]["psnr_db"] == res["end_to_end"]["psnr_db"]


def test_the_lens_room_bench_repeats_the_baseline_behind_a_perfect_lens(resumed_run, tmp_path, load_bench):
    """benches/lens_room.py on a finished run: the baseline's schedule and held-out set again,
    the lens replaced by a perfect one. Its nominal and end-to-end rows are the run's own."""
    bench = load_bench("lens_room")
    res = resumed_run["res"]
    bench.main([str(resumed_run["out"]), "--out", str(tmp_path), "--threads", "1", "--quiet"])
    (room,) = json.loads((tmp_path / "lens_room.json").read_text())
    assert room["updates"] == res["training"]["nominal"]["updates"]  # the same budget as the baseline
    for who in ("nominal", "end_to_end"):
        assert room["means"][who]["psnr_db"] == pytest.approx(res[who]["psnr_db"], rel=1e-9)
    e2e = room["end_to_end_minus_nominal"][res["headline_position"]]["psnr_db"]
    assert e2e["mean"] == pytest.approx(res["paired"]["psnr_db"]["mean"], rel=1e-9)
    # the perfect lens (no shading, the renderer bypassed) is not the run's own delta lens
    assert room["means"]["run_ideal_lens"] == res["ideal_lens"]
    assert room["means"]["perfect_finetuned"]["psnr_db"] != pytest.approx(res["ideal_lens"]["psnr_db"], abs=1e-6)
    d = room["perfect_minus_nominal"]["frame"]["psnr_db"]
    assert d["ci95"][0] <= d["mean"] <= d["ci95"][1]
    assert "ideal minus nominal" in (tmp_path / "lens_room.md").read_text()


def test_the_lens_room_benchs_delta_lens_is_the_runs_ideal_lens(resumed_run, tmp_path, load_bench):
    """benches/lens_room.py --lens delta and the run's ideal_lens are one construction
    (camera_design.build.delta_lens) on one budget: the same figures."""
    bench = load_bench("lens_room")
    res = resumed_run["res"]
    bench.main([str(resumed_run["out"]), "--out", str(tmp_path), "--threads", "1", "--quiet", "--lens", "delta"])
    (room,) = json.loads((tmp_path / "lens_room-delta.json").read_text())
    assert room["updates"] == res["training"]["ideal_lens"]["updates"]
    got, ideal = room["means"]["perfect_finetuned"], res["ideal_lens"]
    for m in ("psnr_db", "ssim", "lpips", "haarpsi"):
        assert got[m] == pytest.approx(ideal[m], rel=1e-6), m
        for pos in ("frame", "centre", "corner"):
            assert got["by_position"][pos][m] == pytest.approx(ideal["by_position"][pos][m], rel=1e-6), (pos, m)
    d = room["perfect_minus_end_to_end"]["frame"]["psnr_db"]["mean"]
    assert d == pytest.approx(-res["paired_against"]["ideal_lens"]["paired"]["psnr_db"]["mean"], rel=1e-6)


def test_a_finished_run_is_evaluated_on_the_test_split_without_training_again(
    resumed_run, tmp_path, optix, smoke_design
):
    """--test-photos on a finished run: every camera on the test split's photographs at native
    scale (docs/test-split.md), paired against the end-to-end camera, the held-out set's
    baseline kept; nothing trains again, and a training corpus is refused as a test split."""
    import shutil

    import imageio.v3 as iio
    import numpy as np

    from optix_e2e.scenes.corpus import prepare_corpus

    rng = np.random.default_rng(0)
    src = tmp_path / "photos"
    src.mkdir()
    for i in range(3):
        iio.imwrite(src / f"p{i}.png", rng.integers(0, 256, (170, 200, 3), dtype=np.uint8))
    prepare_corpus("folder", src, tmp_path / "test", licence="made by the test", role="test")
    prepare_corpus("folder", src, tmp_path / "train", licence="made by the test")
    run = tmp_path / "run"
    shutil.copytree(resumed_run["out"], run)
    args = smoke_design("iq-software", run, "--config", resumed_run["cfg"])
    r = optix(*args, "--test-photos", tmp_path / "train")
    assert r.returncode == 1 and "a training corpus" in r.stderr and r.stderr.count("\n") == 1
    r = optix(*args, "--test-photos", tmp_path / "test")
    assert r.returncode == 0, r.stdout + r.stderr
    assert (
        f"end_to_end: resuming at step {N_STEPS} of {N_STEPS}" in r.stdout and "test split (3 photographs" in r.stdout
    )
    res = json.loads((run / "results.json").read_text())
    t = res["test_split"]
    assert t["n_images"] == 3 and t["n_samples"] == 3 * 6 and t["photos"]["split"] == "test"
    assert t["baseline"] == res["baseline"]["camera"]
    assert set(t["means"]) == {"nominal", "end_to_end", "nominal_untuned", "ideal_lens"}
    assert set(t["paired_against"]) == {"nominal", "nominal_untuned", "ideal_lens"}
    rows = {who: json.loads((run / f"test_{who}.json").read_text())["rows"] for who in t["means"]}
    head = [x for x in rows["end_to_end"] if x["position"] == "frame"]
    assert t["means"]["end_to_end"]["psnr_db"] == pytest.approx(np.mean([x["psnr_db"] for x in head]))
    d = {
        img: np.mean([x["psnr_db"] for x in rows["end_to_end"] if x["image"] == img and x["position"] == "frame"])
        - np.mean([x["psnr_db"] for x in rows["nominal"] if x["image"] == img and x["position"] == "frame"])
        for img in {x["image"] for x in head}
    }
    assert t["paired_against"]["nominal"]["paired"]["psnr_db"]["mean"] == pytest.approx(np.mean(list(d.values())))
    # the held-out figures are those of the run, untouched
    for k in ("nominal", "end_to_end", "nominal_untuned", "ideal_lens", "baseline"):
        assert res[k] == resumed_run["res"][k], k
    assert (run / "test_metrics.csv").read_text().count("\n") == 1 + 4 * 18
