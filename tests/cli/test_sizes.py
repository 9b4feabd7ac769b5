"""Oversized requests: each is one clear error that says what the request
would need, before anything is allocated or written; never an allocation failure that aborts
the process (exit 134). A long Huygens sum shows its progress and stops on request."""

import subprocess
import sys

import numpy as np
import pytest

from optix_e2e import _engine
from optix_e2e.lens import Lens


@pytest.fixture(scope="module")
def cooke():
    return Lens.load("cooke-f50")


def _optix(*args):
    return subprocess.run([sys.executable, "-m", "optix_e2e", *map(str, args)], capture_output=True, text=True)


def test_fft_grid_beyond_memory_is_one_error(tmp_path):
    r = _optix("psf", "cooke-f50", "--method", "fft", "--fft-grid", "100000", "--out", tmp_path / "p.npy")
    assert r.returncode == 1 and r.stderr.strip().startswith("Error:") and "fft_grid 100000" in r.stderr, r.stderr
    r = _optix("psf", "cooke-f50", "--method", "fft", "--fft-grid", "60000", "--out", tmp_path / "p.npy")
    assert r.returncode == 1 and "would need about" in r.stderr and "FFT grid 60000^2" in r.stderr, r.stderr
    assert not (tmp_path / "p.npy").exists()


def test_spot_rings_beyond_memory(cooke):
    with pytest.raises(ValueError, match=r"100000-ring spot .* would need about .*TiB"):
        cooke.spot(0.0, rings=100000)


def test_batch_sizes_checked_before_allocation(cooke):
    js = [cooke.to_engine_json()]
    with pytest.raises(ValueError, match="100001 sensor pixels across"):
        _engine.psf_batch(js, [0.0], cooke.rgb_channels(), sensor=(5.86, 100001))
    with pytest.raises(ValueError, match=r"psf_batch would need about .*PSFs 2000x50x3x4096x4096"):
        _engine.psf_batch(js * 2000, [0.0] * 50, cooke.rgb_channels(), size=4096)


def test_dataset_window_beyond_the_engine_and_memory_writes_nothing(tmp_path):
    out = tmp_path / "ds"
    r = _optix("dataset", "paper-triplet", "-n", "64", "--seed", "1", "--out", out, "--window-um", "100000")
    assert r.returncode == 1 and "100000 pixels across" in r.stderr, r.stderr
    r = _optix("dataset", "paper-triplet", "-n", "64", "--seed", "1", "--out", out, "--window-um", "8000")
    assert r.returncode == 1 and "would need about" in r.stderr and "shard buffers" in r.stderr, r.stderr
    assert not out.exists()


def test_huygens_reports_progress_and_stops_on_request(cooke):
    """A 1024 x 1024 Huygens PSF at 0.5 um (the exact distance sum: minutes): the callback sees
    rows done of 1024; raising in it stops the sum and the exception reaches the caller."""
    seen = []

    def progress(done, total):
        seen.append((done, total))
        if len(seen) >= 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        cooke.psf(0.0, 550.0, "huygens", pixel_um=0.5, size=1024, pupil_samples=128, progress=progress)
    assert len(seen) == 2 and all(t in (0, 1024) for _, t in seen) and seen[-1][0] < 1024
    # a small one with a callback gives the same PSF as without
    a, _ = cooke.psf(0.0, 550.0, "huygens", pixel_um=1.0, size=64, pupil_samples=64)
    b, _ = cooke.psf(0.0, 550.0, "huygens", pixel_um=1.0, size=64, pupil_samples=64, progress=lambda d, t: None)
    np.testing.assert_array_equal(a, b)
