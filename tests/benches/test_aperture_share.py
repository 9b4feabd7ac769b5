"""benches/aperture_share.py: the share of Adam's full step is the aperture's change in the
sigmoid's argument over lr x step scale x lens steps (checked on a hand-made run whose
aperture takes half a full step at every step, and on one that turns back)."""

from __future__ import annotations

import csv
import json
import math

import pytest


def _run(path, us: list[float], scale: float, lr: float = 0.03, optimizer: str = "alg1"):
    lo, hi = 2.8, 4.6
    f = [lo + (hi - lo) / (1 + math.exp(-u)) for u in us]
    path.mkdir()
    names = ["s_1_radius", "f_number"]
    (path / "config.json").write_text(
        json.dumps({"optimizer": optimizer, "lr_optics": lr, "lr_vanilla": 1e-3, "lens_steps": "range"})
    )
    (path / "results.json").write_text(
        json.dumps(
            {
                "design": {"parameters": names, "step_scale": [1.0, scale]},
                "space": {"ranges": {"s_1_radius": [24.0, 36.0], "f_number": [lo, hi]}},
            }
        )
    )
    with open(path / "lens_path.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["step", "block", "cut", *names])
        for k, x in enumerate(f):
            w.writerow([k, "start" if k == 0 else "optics", 0, 30.0, x])


def test_half_steps_give_a_share_of_one_half(tmp_path, load_bench):
    u0, lr, scale = math.log(0.8 / 0.2), 0.03, 2.5
    _run(tmp_path / "a", [u0 - 0.5 * lr * scale * k for k in range(41)], scale, lr)
    # turning back: 30 full steps down, 10 up, share (30 - 10) / 40
    down = [u0 - lr * k for k in range(31)]
    _run(tmp_path / "b", down + [down[-1] + lr * k for k in range(1, 11)], 1.0, lr)
    rows = load_bench("aperture_share").main([str(tmp_path / "a"), str(tmp_path / "b")])
    assert rows[0]["share_of_full_step"] == pytest.approx(0.5, rel=1e-6)
    assert rows[0]["steps_opening"] == 40 and rows[0]["f_number_end"] < rows[0]["f_number_start"] == pytest.approx(4.24)
    assert rows[1]["share_of_full_step"] == pytest.approx(0.5, rel=1e-6) and rows[1]["steps_opening"] == 30


def test_a_folder_that_is_not_a_finished_run_is_one_line(tmp_path, load_bench):
    with pytest.raises(SystemExit, match="not a finished design run"):
        load_bench("aperture_share").main([str(tmp_path)])
