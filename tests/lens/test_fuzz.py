"""Seeded fuzz test of lens input files: mutants of the bundled lenses' JSON and
.zmx (tests/lens/fuzz_lens_inputs.py) give results without NaN or the project's own errors, and
the process that runs them ends normally (an abort would show as a signal exit). The count
bounds the run; 600 mutants take a few seconds here. Deeper runs: the script with --n."""

import json
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.slow
def test_mutated_lens_files_give_our_errors_or_clean_results(tmp_path):
    out = tmp_path / "fuzz.json"
    script = Path(__file__).with_name("fuzz_lens_inputs.py")
    r = subprocess.run(
        [sys.executable, str(script), "--n", "600", "--seed", "0", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, f"the fuzzing process ended with {r.returncode}: {r.stderr[-2000:]}"
    rep = json.loads(out.read_text())
    assert rep["n"] == 600 and sum(rep["outcomes"].values()) == 600
    assert not rep["unexpected"], json.dumps(rep["unexpected"][:3], indent=1)[:4000]
    # the mutants reach every stage: some load and compute, some are refused by each reader
    assert rep["outcomes"].get("ok", 0) > 50
    assert {"ZemaxError", "PrescriptionError"} <= set(rep["outcomes"]) or "LensLoadError" in rep["outcomes"]
