"""optix_e2e.io: every file the package writes is whole or absent; a write that fails (a full
disk) leaves the old file and no temporary; TensorBoard's writer thread failing reaches the run
as one OSError, not a thread's traceback."""

from __future__ import annotations

import errno
import json

import numpy as np
import pytest

from optix_e2e import io


def _full(*_a, **_k):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_each_writer_writes_the_file_whole(tmp_path):
    io.write_csv_atomic(tmp_path / "a.csv", [[1, "x"], [2, "y"]], header=["n", "s"])
    assert (tmp_path / "a.csv").read_bytes() == b"n,s\r\n1,x\r\n2,y\r\n"
    io.write_record_atomic(tmp_path / "r.json", {"a": float("nan"), "b": np.float32(2.5)})
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": None, "b": 2.5}  # strict JSON
    io.save_npy_atomic(tmp_path / "x.npy", np.arange(6.0).reshape(2, 3))
    assert np.array_equal(np.load(tmp_path / "x.npy"), np.arange(6.0).reshape(2, 3))
    io.save_image(tmp_path / "i.png", np.zeros((4, 5, 3), np.uint8))
    import imageio.v3 as iio

    assert iio.imread(tmp_path / "i.png").shape == (4, 5, 3)
    from matplotlib.figure import Figure

    fig = Figure()
    fig.add_subplot().plot([0, 1])
    io.save_figure(fig, tmp_path / "f.png", dpi=50)
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "f.png", "i.png", "r.json", "x.npy"]


def test_a_write_that_fails_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    (tmp_path / "a.json").write_text('{"old": 1}')
    monkeypatch.setattr(io.os, "fsync", _full)
    with pytest.raises(OSError, match="No space left"):
        io.write_record_atomic(tmp_path / "a.json", {"new": 2})
    assert (tmp_path / "a.json").read_text() == '{"old": 1}'
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_tensorboards_writer_thread_failing_is_one_error_in_the_run(tmp_path, capfd):
    writer = io.tensorboard_writer(tmp_path / "tb")
    writer.add_scalar("x", 1.0, 0)
    writer.flush()
    record = writer._get_file_writer().event_writer._async_writer._writer
    record.write = _full  # the disk fills up under the writer thread
    with pytest.raises(OSError, match="No space left"):
        for step in range(1, 10_000):
            writer.add_scalar("x", float(step), step)
            writer.flush()
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Exception in thread" not in err
