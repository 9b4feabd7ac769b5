"""benches/detection_seeds.py: the per-seed rows are the runs' own figures and the interval over
seeds is Student's t of the per-seed differences (checked on two hand-made results.json)."""

from __future__ import annotations

import json

import pytest


def _results(seed: int, gain: float) -> dict:
    def cam(f, m):
        return {
            "f_number": f,
            "rms_spot_um": [7.0, 9.0, 12.0],
            "report_fields_deg": [0.0, 7.45, 14.9],
            "map_50": m,
            "map": m / 2,
            "dark": {"map_50": m - 0.1, "map": m / 3},
        }

    paired = {"mean": gain, "ci95": [gain - 0.01, gain + 0.01]}
    return {
        "task": "detection",
        "seed": seed,
        "budget": "full",
        "optimizer": "alg1",
        "nominal": cam(4.4, 0.70),
        "end_to_end": cam(4.0 - 0.1 * seed, 0.70 + gain),
        "training": {"end_to_end": {"cut_steps": 0, "lens_steps": 350}},
        "paired": {"n_images": 200, "map_50": paired, "map": paired, "dark": {"map_50": paired, "map": paired}},
    }


def test_the_seed_interval_is_students_t_over_the_per_seed_differences(tmp_path, load_bench):
    gains = [0.074, 0.020, 0.050]
    runs = []
    for s, g in enumerate(gains):
        run = tmp_path / f"seed{s}"
        run.mkdir()
        (run / "results.json").write_text(json.dumps(_results(s, g)))
        runs.append(str(run))
    load_bench("detection_seeds").main([*runs, "--out", str(tmp_path / "table")])
    out = json.loads((tmp_path / "table.json").read_text())
    s = out["over_seeds"]["mAP@0.5"]
    assert s["per_seed"] == gains and s["mean"] == pytest.approx(sum(gains) / 3)
    half = 4.302653 * (sum((g - s["mean"]) ** 2 for g in gains) / 2) ** 0.5 / 3**0.5  # t(0.975, 2 dof)
    assert s["seeds_ci95"] == pytest.approx([s["mean"] - half, s["mean"] + half], rel=1e-5)
    assert out["over_seeds"]["f_number_end_to_end"]["per_seed"] == pytest.approx([4.0, 3.9, 3.8])
    md = (tmp_path / "table.md").read_text()
    assert "4.40 -> 3.90" in md and "+0.074 [+0.064, +0.084]" in md and "mean of 3" in md


def test_a_run_of_another_task_is_refused(tmp_path, load_bench):
    (tmp_path / "results.json").write_text(json.dumps({**_results(0, 0.1), "task": "iq-software"}))
    with pytest.raises(SystemExit, match="not a detection run"):
        load_bench("detection_seeds").main([str(tmp_path), "--out", str(tmp_path / "t")])


def test_a_folder_without_results_is_one_line(tmp_path, load_bench):
    with pytest.raises(SystemExit, match="not a finished design run"):
        load_bench("detection_seeds").main([str(tmp_path), "--out", str(tmp_path / "t")])
