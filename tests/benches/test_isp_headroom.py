"""benches/isp_headroom.py on photographs (--photos): the samples are the corpus's at native
scale (tasks/samples.py photo_test_set), every figure carries LPIPS and the design runs' task
loss, and the split asked for is the one scored (a training corpus is no test split)."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest

from optix_e2e.scenes.corpus import prepare_corpus


@pytest.mark.slow
def test_the_headroom_bench_scores_a_corpus_at_native_scale(tmp_path, load_bench):
    bench = load_bench("isp_headroom")
    src = tmp_path / "src"
    src.mkdir()
    iio.imwrite(src / "p.png", np.random.default_rng(0).integers(0, 256, (170, 180, 3), dtype=np.uint8))
    prepare_corpus("folder", src, tmp_path / "test", licence="made by the test", role="test")
    out = bench.main(
        [
            "--photos",
            str(tmp_path / "test"),
            "--split",
            "test",
            "--size",
            "32",
            "--threads",
            "1",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert out["held_out"]["n_images"] == 1 and out["held_out"]["n_samples"] == 4
    assert out["held_out"]["set"]["split"] == "test"
    row = out["results"]["normal/software_isp.pt/nominal"]
    assert row["psnr_db_procedural"] is None and row["psnr_db_photos"] == pytest.approx(row["psnr_db"])
    assert 0 < row["lpips"] < 1 and row["l1_plus_lpips"] > row["lpips"]
    assert (
        out["results"]["normal/bound/no-cfa/perfect"]["psnr_db"] > out["results"]["normal/classical/perfect"]["psnr_db"]
    )
    with pytest.raises(SystemExit, match="untouched test split"):  # one line, no traceback
        bench.main(["--photos", str(tmp_path / "test"), "--split", "val", "--size", "32", "--out", str(tmp_path / "o")])
