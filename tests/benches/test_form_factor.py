"""benches/form_factor.py on hand-made run folders: the table's means are the runs' own test-split
figures, the differences are paired per photograph within a seed (seed k of one space against
seed k of the other) and Student's t over the seeds, 1 - LPIPS signed so that higher is better."""

from __future__ import annotations

import csv
import json
import shutil

import pytest

from optix_e2e.lens.model import BUNDLED_DIR

CAMERAS = ("nominal_untuned", "nominal", "end_to_end", "ideal_lens")
IMAGES = ("a", "b", "c")
# PSNR offsets per camera; each seed adds its own shift to end_to_end
BASE = {
    "paper-triplet": {"nominal_untuned": 26.0, "nominal": 26.5, "end_to_end": 27.0, "ideal_lens": 30.0},
    "paper-doublet": {"nominal_untuned": 24.0, "nominal": 24.5, "end_to_end": 26.0, "ideal_lens": 29.0},
}
SHIFT = {0: 0.0, 1: 0.3, 2: -0.1}


def _psnr(space: str, who: str, seed: int, image: int) -> float:
    return BASE[space][who] + (SHIFT[seed] if who == "end_to_end" else 0.0) + 0.1 * image


def _run(root, space: str, seed: int) -> None:
    run = root / "runs" / f"{space}-seed{seed}"
    (run / "lens").mkdir(parents=True)
    rows = []
    for who in CAMERAS:
        for k, img in enumerate(IMAGES):
            for pos in ("frame", "frame", "corner"):
                p = _psnr(space, who, seed, k) + (-3.0 if pos == "corner" else 0.0)  # the corner is no headline
                rows.append([who, img, pos, 0.5, p, 0.8, 0.1 + 0.01 * k, 0.7])
    with open(run / "test_metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["camera", "image", "position", "radius", "psnr_db", "ssim", "lpips", "haarpsi"])
        w.writerows(rows)
    means = {}
    for who in CAMERAS:
        psnr = sum(_psnr(space, who, seed, k) for k in range(3)) / 3
        by = {"frame": {"psnr_db": psnr}, "corner": {"psnr_db": psnr - 3.0}}
        means[who] = {"psnr_db": psnr, "ssim": 0.8, "one_minus_lpips": 0.89, "by_position": by}
    res = {"test_split": {"means": means}, "nominal": {"psnr_db": 25.0}, "end_to_end": {"psnr_db": 25.5}, "wall_s": 1.0}
    (run / "results.json").write_text(json.dumps(res))
    for who in ("nominal", "end_to_end"):
        shutil.copy(BUNDLED_DIR / f"{space}.json", run / "lens" / f"{who}.json")
        (run / "report" / who).mkdir(parents=True)
        fields = [{"field_deg": f, "rms_spot_um": 10.0 + f} for f in (0.0, 14.9)]
        (run / "report" / who / "report.json").write_text(json.dumps({"fields": fields}))


def test_the_table_pairs_photographs_within_a_seed_and_seeds_by_t(tmp_path, load_bench):
    for space in BASE:
        for seed in SHIFT:
            _run(tmp_path, space, seed)
    load_bench("form_factor").main(["--out", str(tmp_path), "--test-photos", "unused", "--seeds", "0", "1", "2"])
    t = json.loads((tmp_path / "form_factor.json").read_text())
    dbl = t["spaces"]["paper-doublet"]
    assert dbl["nominal_lens"]["elements"] == 2 and t["spaces"]["paper-triplet"]["nominal_lens"]["elements"] == 3
    assert dbl["nominal_lens"]["total_track_mm"] < t["spaces"]["paper-triplet"]["nominal_lens"]["total_track_mm"]
    assert dbl["test_split"]["end_to_end"]["psnr_db"]["per_seed"] == pytest.approx([26.1, 26.4, 26.0])
    d = t["differences"]["paper-doublet end-to-end minus paper-doublet nominal + fine-tuned processing"]["psnr_db"]
    gains = [1.5 + SHIFT[s] for s in SHIFT]
    assert d["per_seed"] == pytest.approx(gains) and d["mean"] == pytest.approx(sum(gains) / 3)
    assert d["per_seed_ci95"][0] == pytest.approx([1.5, 1.5])  # the same gain on every photograph
    half = 4.302653 * (sum((g - d["mean"]) ** 2 for g in gains) / 2) ** 0.5 / 3**0.5  # t(0.975, 2 dof)
    assert d["seeds_ci95"] == pytest.approx([d["mean"] - half, d["mean"] + half], rel=1e-5)
    x = t["differences"]["doublet end-to-end minus triplet nominal + fine-tuned processing"]
    assert x["psnr_db"]["per_seed"] == pytest.approx([26.0 - 26.5 + SHIFT[s] for s in SHIFT])
    assert x["one_minus_lpips"]["per_seed"] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)
    assert dbl["test_split"]["end_to_end"]["psnr_db_by_position"]["corner"] == pytest.approx(
        (26.1 + 26.4 + 26.0) / 3 - 3.0
    )
    md = (tmp_path / "form_factor.md").read_text()
    assert "| paper-doublet | end_to_end | 23.17 | 26.17 |" in md  # corner, frame
    assert "| paper-doublet | 2 |" in md and "doublet end-to-end minus triplet end-to-end" in md
    assert (tmp_path / "form_factor.png").stat().st_size > 10_000 and (tmp_path / "form_factor.csv").is_file()
