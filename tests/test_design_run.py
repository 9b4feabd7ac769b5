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


def _design(out, *extra, env=None):
    return [
        sys.executable,
        "-m",
        "optix_e2e",
        "design",
        "iq-software",
        "--out",
        str(out),
        "--budget",
        "smoke",
        "--threads",
        "1",
        "--quiet",
        *extra,
    ]


def test_a_smoke_design_run_writes_every_output_and_resumes_after_kill_9(tmp_path):
    out = tmp_path / "run"
    cfg = tmp_path / "c.toml"
    cfg.write_text("n_cycles = 3\ncheckpoint_every = 1\n")  # 3 x (2 + 2) + 2 = 14 steps, a checkpoint after each
    p = subprocess.Popen(_design(out, "--config", str(cfg)), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    state = out / "end_to_end_state.pt"
    deadline = time.time() + 240
    while not state.is_file() and time.time() < deadline and p.poll() is None:
        time.sleep(0.05)
    assert p.poll() is None, p.stdout.read().decode()
    assert state.is_file(), "no checkpoint within the deadline"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert not (out / "results.json").exists()
    from optix_e2e.torchfile import load_plain

    before = load_plain(state, "design checkpoint")
    t_kill = int(before["optimizer"]["t"])
    assert 1 <= t_kill < 14 and len(before["history"]) == t_kill
    # other settings are refused; the same command resumes and finishes
    r = subprocess.run(_design(out, "--config", str(cfg), "--seed", "1"), capture_output=True, text=True)
    assert r.returncode == 1 and "other settings" in r.stdout + r.stderr and "seed" in r.stdout + r.stderr
    r = subprocess.run(_design(out, "--config", str(cfg)), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"end_to_end: resuming at step {t_kill} of 14" in r.stdout, r.stdout
    res = json.loads((out / "results.json").read_text())
    for k in ("task", "optics_eval", "nominal", "end_to_end", "paired", "lens_zmx", "wall_s"):
        assert k in res, k
    assert res["optics_eval"] == "exact" and res["task"] == "iq-software"
    for who in ("nominal", "end_to_end"):
        for m in ("psnr_db", "ssim", "lpips", "haarpsi"):
            assert isinstance(res[who][m], float) and isinstance(res[who]["surrogate"][m], float)
    # the lens's room: the nominal camera's processing behind a perfect lens, the same keys
    assert set(res["perfect_lens"]) == set(res["nominal"]) - {"surrogate"}
    assert res["perfect_lens"]["n_samples"] == res["nominal"]["n_samples"] and "perfect lens" in r.stdout
    for m in ("psnr_db", "ssim", "lpips", "haarpsi"):
        lo, hi = res["paired"][m]["ci95"]
        assert lo <= res["paired"][m]["mean"] <= hi
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
    # the steps ran once each, in order, across the kill
    rows = [r for r in csv.DictReader(open(out / "history.csv")) if r["run"] == "end_to_end"]
    assert [int(r["step"]) for r in rows] == list(range(1, 15))
    # ... and the steps before the kill were not run again (a restart would re-time them)
    assert [float(r["seconds"]) for r in rows[:t_kill]] == [h["seconds"] for h in before["history"]]
    # the exported lens reloads to the same design, in .zmx and JSON
    z, j = Lens.load(out / res["lens_zmx"]), Lens.load(out / res["lens_json"])
    assert z.paraxial()["efl_mm"] == pytest.approx(j.paraxial()["efl_mm"], rel=1e-9)
    for f in (0.0, 14.9):
        assert z.spot(f)["rms_um"] == pytest.approx(j.spot(f)["rms_um"], rel=1e-6)
    assert res["design"]["checks"]["inside_space"] and res["design"]["checks"]["manufacturable"]
    assert res["design"]["checks"]["refocused"], res["design"]["checks"]
    win = res["exact_psf_energy_in_window"]
    for who in ("nominal", "end_to_end"):
        assert len(win[who]) == len(win["fields_deg"]) and all(0.5 < e <= 1.01 for e in win[who]), win
    # the same run uninterrupted lands on the same lens
    r = subprocess.run(_design(tmp_path / "again", "--config", str(cfg)), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    again = json.loads((tmp_path / "again" / "results.json").read_text())
    assert again["design"]["end_to_end"] == res["design"]["end_to_end"]
    assert again["end_to_end"]["psnr_db"] == res["end_to_end"]["psnr_db"]
