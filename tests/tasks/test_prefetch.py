"""The next training batch made beside the step (tasks/prefetch.py)."""

from __future__ import annotations

import threading

import pytest
import torch

from optix_e2e.tasks.prefetch import Prefetched


def _recorder():
    calls, threads = [], []

    def make(t):
        calls.append(t)
        threads.append(threading.current_thread().name)
        return {"t": t}

    return make, calls, threads


def test_items_are_made_ahead_in_order_and_asked_again_the_same():
    make, calls, threads = _recorder()
    with Prefetched(make, last=3) as stream:
        first = stream(0)
        assert first == {"t": 0} and stream(0) is first  # the same t: the same item, not made again
        assert [stream(t)["t"] for t in (1, 2, 3)] == [1, 2, 3]
        assert stream.prefetched == 3
    assert calls == [0, 1, 2, 3]  # nothing past ``last``
    assert threads[0] == threading.main_thread().name and all(n.startswith("prefetch") for n in threads[1:])


def test_a_jump_waits_for_the_batch_being_made_and_makes_the_asked_one():
    make, calls, _ = _recorder()
    with Prefetched(make) as stream:
        stream(0)
        assert stream(5)["t"] == 5 and stream.prefetched == 0  # resumed elsewhere: made inline
        assert stream(6)["t"] == 6 and stream.prefetched == 1
    assert calls[:3] == [0, 1, 5]  # batch 1 finished (never two makes at once), then dropped


def test_without_ahead_everything_is_made_inline():
    make, calls, threads = _recorder()
    stream = Prefetched(make, ahead=False)
    assert [stream(t)["t"] for t in range(3)] == [0, 1, 2] and stream.prefetched == 0
    assert set(threads) == {threading.main_thread().name}
    stream.close()


def test_an_error_making_a_batch_comes_out_where_it_is_asked_for():
    def make(t):
        if t == 1:
            raise ValueError("bad batch 1")
        return t

    with Prefetched(make) as stream:
        assert stream(0) == 0
        with pytest.raises(ValueError, match="bad batch 1"):
            stream(1)


@pytest.mark.slow
def test_a_design_training_prefetching_repeats_the_inline_one(tmp_path, monkeypatch):
    """The design run's training with its batches made beside the step (forced on the CPU):
    the same losses and the same camera as made inline, and the batches came from the thread."""
    from optix_e2e.camera_design import training
    from optix_e2e.camera_design.build import build_camera, load_surrogate, make_optimizer
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.tasks import SensorFrame

    made = []
    real = Prefetched.__call__

    def counting(self, t):
        item = real(self, t)
        made.append(self.prefetched)
        return item

    def run(out, ahead):
        monkeypatch.setattr(training, "PREFETCH_ON_CPU", ahead)
        cfg = make_config("smoke", threads=1)
        sur, frame = load_surrogate(cfg.surrogate), SensorFrame()
        torch.manual_seed(0)
        cam = build_camera(cfg, sur, frame=frame)
        res = training.train(cfg, cam, make_optimizer(cfg, cam, cfg.optimizer), out, "e", progress=False, frame=frame)
        return res, cam

    monkeypatch.setattr(Prefetched, "__call__", counting)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    inline, cam_a = run(tmp_path / "a", False)
    assert made and max(made) == 0
    made.clear()
    ahead, cam_b = run(tmp_path / "b", True)
    assert max(made) == ahead["steps"] - 1  # every batch after the first came from the thread
    assert [h["loss"] for h in ahead["history"]] == [h["loss"] for h in inline["history"]]
    for (k, a), b in zip(cam_a.state_dict().items(), cam_b.state_dict().values()):
        assert torch.equal(a, b), k
