"""benches/dataset.py: the whole command and each phase of the same generation are measured,
and the phases account for the generator's time (timers around its stages, not a model)."""

from __future__ import annotations

import pytest


@pytest.mark.slow
def test_the_dataset_bench_times_the_command_and_its_phases(tmp_path, load_bench):
    from optix_e2e import engine

    bench = load_bench("dataset")
    before = engine.psf_batch
    out = bench.main(["-n", "4", "--json", "--out", str(tmp_path)])
    assert engine.psf_batch is before  # the phases' timers are taken off again
    assert (tmp_path / "dataset_speed.json").is_file()
    w, p = out["whole_command"], out["phases"]
    assert w["seconds"] > 0 and w["designs_per_s_end_to_end"] == pytest.approx(4 / w["seconds"])
    assert p["n_failed"] == 0 and p["psf_batch_s"] > 0 and p["refocus_s"] > 0 and p["sampling_s"] > 0
    # the stages timed inside generate add up to its own time (the rest is what is left)
    assert p["refocus_s"] + p["psf_batch_s"] + p["generate_rest_s"] == pytest.approx(p["generate_s"])
    assert p["generate_rest_s"] >= 0 and "optiland" not in out
