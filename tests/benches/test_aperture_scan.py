"""benches/aperture_scan.py: a detection run's end-to-end lens at other apertures behind its
own processing. Its own aperture must be among the lenses with zero differences, each lens
must reach the sensor at its f-number, and each paired difference must be its two cells'."""

import json

import pytest


@pytest.mark.slow
def test_the_aperture_scan_crosses_the_runs_lens_with_other_apertures(tmp_path, optix, smoke_design, load_bench):
    run = tmp_path / "det"
    r = optix(*smoke_design("detection", run))
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads((run / "results.json").read_text())
    own = res["end_to_end"]["f_number"]
    bench = load_bench("aperture_scan")
    out = bench.main(
        [
            str(run),
            "--out",
            str(tmp_path / "scan"),
            "--f-numbers",
            "4.1",
            "4.6",
            "--batches",
            "3",
            "--scenes",
            "4",
            "--threads",
            "1",
        ]
    )
    rows = {round(x["f_number"], 4): x for x in out["rows"]}
    assert set(rows) == {4.1, 4.6, round(own, 4)}
    mine = next(x for x in out["rows"] if x["own"])
    assert mine["f_number"] == pytest.approx(own, abs=1e-6)
    assert mine["loss_minus_own"]["mean"] == 0.0 and mine["map_50_minus_own"]["mean"] == 0.0
    for x in out["rows"]:
        assert x["loss_minus_own"]["mean"] == pytest.approx(x["loss"] - mine["loss"], abs=1e-9)
        # mAP is torchmetrics' float32: its differences agree to float32's rounding of values near 1
        assert x["map_50_minus_own"]["mean"] == pytest.approx(x["map_50"] - mine["map_50"], abs=1e-6)
        lo, hi = x["loss_minus_own"]["ci95"]
        assert lo <= x["loss_minus_own"]["mean"] <= hi
    # more light through the same lens: the faster aperture's images are less noisy, so its
    # loss differs from the slower one's (the scan moves the sensor's light, not only the PSFs)
    assert rows[4.1]["loss"] != rows[4.6]["loss"]
    for f in ("aperture_scan.json", "aperture_scan.csv", "aperture_scan.png"):
        assert (tmp_path / "scan" / f).is_file()


def test_the_aperture_scan_leaves_a_folder_of_other_files_alone(tmp_path, load_bench):
    bench = load_bench("aperture_scan")
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(SystemExit):
        bench.main([str(tmp_path / "no_run"), "--out", str(tmp_path)])
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]
