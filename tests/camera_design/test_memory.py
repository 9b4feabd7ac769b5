"""A design run's memory is estimated before it starts (camera_design/memory.py): a batch that
cannot fit is refused in one line before anything is written."""

from __future__ import annotations

import resource

import pytest

from optix_e2e.camera_design import memory
from optix_e2e.camera_design.config import make_config
from optix_e2e.errors import InputError


@pytest.mark.parametrize("task", ["iq-software", "iq-hardware", "low-light", "detection"])
def test_the_budgets_fit_a_small_machine_and_the_estimate_grows_with_the_batch(task):
    margin = 20  # the paper triplet's PSF half-window at the sensor's pitch
    for budget in ("smoke", "quick", "full"):
        cfg = make_config(budget, task=task)
        assert 1.0 < memory.estimate_bytes(cfg, margin) / 2**30 < 4.0, budget  # modelled, GiB
    small, big = make_config("quick", task=task, batch=2), make_config("quick", task=task, batch=8)
    assert memory.estimate_bytes(big, margin) > memory.estimate_bytes(small, margin)
    # the fit on the measured points (benches/results/memory_model) is what the run checks against
    assert set(memory.memory_model()) == {"iq-software", "iq-hardware", "detection"}


def test_an_address_space_limit_is_what_is_available(monkeypatch):
    monkeypatch.setattr(memory.resource, "getrlimit", lambda _: (10 * 2**30, resource.RLIM_INFINITY))
    have, what = memory.available_bytes()
    assert have < 10 * 2**30 and "ulimit -v" in what


def test_a_batch_that_cannot_fit_is_refused_before_the_run_folder_is_made(tmp_path, optix):
    (tmp_path / "big.toml").write_text("crop = 1024\nbatch = 256\n")
    out = tmp_path / "run"
    r = optix("design", "iq-software", "--budget", "smoke", "--config", tmp_path / "big.toml", "--out", out, "--quiet")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "a training step of batch 256 at crop 1024 x 1024" in r.stderr and "GiB" in r.stderr
    assert "Traceback" not in r.stderr and not out.exists()
    cfg = make_config("smoke", tmp_path / "big.toml")
    with pytest.raises(InputError, match="lower batch or crop"):
        memory.check_memory(cfg, 20)
