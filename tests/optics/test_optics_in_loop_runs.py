"""Whole `optix design` runs with exact and hybrid optics in the loop: the checks
along the run, the lens steps on exact gradients, the refinements, and a finished run resumed."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest


@pytest.mark.slow
def test_design_runs_with_exact_and_hybrid_optics(tmp_path, optix, smoke_design):
    res = {}
    for mode in ("exact", "hybrid"):
        out = tmp_path / mode
        r = optix(*smoke_design("iq-software", out, "--optics", mode))
        assert r.returncode == 0, r.stdout + r.stderr
        res[mode] = json.loads((out / "results.json").read_text())
        om = res[mode]["optics_model"]
        assert om["mode"] == mode and om["requested"] == mode
        assert [c["step"] for c in om["checks"]] == [0, 3, 6]  # smoke: 6 steps, checks every 3
        for c in om["checks"]:
            assert len(c["network_error_per_field"]) == 13
            assert all(np.isfinite(c["network_error_per_field"]))
        rows = [row for row in csv.DictReader(open(out / "history.csv")) if row["run"] == "end_to_end"]
        if mode == "exact":
            assert {row["optics"] for row in rows} == {"exact"}
            assert om["exact_gradient_steps"] == 4  # 2 optics steps + 2 joint steps
            assert om["final_error_per_field"] == [0.0] * 13
            # every lens step on the engine's one-pass gradient (no difference steps chosen)
            assert om["exact_gradient"] == "one-pass"
            assert om["one_pass_gradients"] == 4 and om["difference_fallbacks"] == 0
            assert om["step_choice"] is None
        else:
            assert om["n_refinements"] >= 1  # the nominal's 23 % is over 2 %
            assert om["events"][0]["event"] == "refine" and om["events"][0]["step"] == 0
        assert {row["optics"] for row in csv.DictReader(open(out / "history.csv")) if row["run"] == "nominal"} == {
            "fixed"
        }
        if mode == "exact":
            continue  # tests/optics/test_optics_in_loop.py resumes a killed exact run
        # the same command again resumes a finished run: the checks come back from the checkpoint
        r = optix(*smoke_design("iq-software", out, "--optics", mode))
        assert r.returncode == 0, r.stdout + r.stderr
        again = json.loads((out / "results.json").read_text())
        assert again["optics_model"]["checks"] == om["checks"]
        assert again["design"]["end_to_end"] == res[mode]["design"]["end_to_end"]
