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
    # the lens's room: the nominal camera's processing behind a perfect lens, the same keys
    assert set(res["perfect_lens"]) == set(res["nominal"]) - {"surrogate"}
    assert res["perfect_lens"]["n_samples"] == res["nominal"]["n_samples"] and "perfect lens" in resumed_run["stdout"]
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
    # what the run prints: the frame headline, then a line each for the centre and the corner
    stdout = resumed_run["stdout"]
    assert "headline: 4 frame positions per image" in stdout
    for pos in ("centre", "corner"):
        lo, hi = by[pos]["psnr_db"]["ci95"]
        assert f"diff {by[pos]['psnr_db']['mean']:+.4f} [{lo:+.4f}, {hi:+.4f}]" in stdout, pos


def test_both_cameras_get_as_many_updates_per_processing_block(resumed_run):
    # n_cycles 3 of (2 optics + 2 ISP steps) then 2 joint steps: every block 3 x 2 + 2 = 8 updates,
    # counted by the optimizers across the kill and the resume
    t = resumed_run["res"]["training"]
    assert t["end_to_end"]["updates"] == {"optics": 8, "isp": 8}
    assert t["nominal"]["updates"] == {"isp": 8} and t["nominal"]["steps"] == 3 * 2 + 2
    assert "the end-to-end run's updates per processing block (isp 8)" in resumed_run["stdout"]


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
    # the fine-tuned processing behind the perfect lens is not the nominal camera's
    assert room["means"]["perfect_finetuned"]["psnr_db"] != pytest.approx(res["perfect_lens"]["psnr_db"], abs=1e-6)
    d = room["perfect_minus_nominal"]["frame"]["psnr_db"]
    assert d["ci95"][0] <= d["mean"] <= d["ci95"][1]
    assert "ideal minus nominal" in (tmp_path / "lens_room.md").read_text()
