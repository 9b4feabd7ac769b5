"""benches/isp_sizes.py: each network's parameters are counted, its speed timed, and its
training's last validation row reported (here the shipped network's own record)."""

from __future__ import annotations

from pathlib import Path

import optix_e2e


def test_the_sizes_bench_reports_parameters_speed_and_validation(tmp_path, load_bench):
    bench = load_bench("isp_sizes")
    shipped = Path(optix_e2e.__file__).parent / "isp" / "bundled" / "software_isp.pt"
    out = bench.main(
        ["--isp", str(shipped), "--size", "32", "--repeats", "1", "--threads", "1", "--out", str(tmp_path)]
    )
    (row,) = out["networks"]
    assert row["parameters"] == 1_605_164 and row["width"] == 32 and row["arch"] == "nafnet"
    assert row["ms_per_megapixel"] > 0 and row["steps"] == row["validation"]["step"]
    assert 20 < row["validation"]["psnr_db"] < 40
    assert (tmp_path / "sizes.md").read_text().count("\n") == 3
