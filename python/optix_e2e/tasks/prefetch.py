"""The next training batch made while the current step runs.

A design run's batches are a seeded stream: batch t depends only on the run's seed, t and its
settings (tasks/samples.py), so batch t + 1 can be made in a background thread while step t
runs on the device, and it is the batch made inline. On a GPU the scenes' CPU work (procedural
scenes, photographs cropped and lit: 160 ms a step on an H100 machine's CPU, docs/gpu.md) then
hides behind the networks'; on a CPU the thread takes cores the step needs (measured in
docs/gpu.md), so the design run prefetches where the camera is not on the CPU.

Calls of ``make`` never overlap: a request for another batch than the one being made waits for
that one first, so ``make`` needs no locks of its own (photograph caches, corpora).
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Generic, TypeVar

T = TypeVar("T")
_NONE = object()


class Prefetched(Generic[T]):
    """``stream(t)`` is ``make(t)``; with ``ahead`` it also starts ``make(t + 1)`` in a background
    thread (not past ``last``), which the next call takes. The same t asked again returns the same
    item. ``prefetched`` counts the items that came from the thread. Close it (or use it as a
    context manager) to end the thread."""

    def __init__(self, make: Callable[[int], T], *, ahead: bool = True, last: int | None = None):
        self.make, self.last = make, last
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="prefetch") if ahead else None
        self._pending: tuple[int, Future] | None = None
        self._held: tuple[int, T] | None = None
        self.prefetched = 0

    def __call__(self, t: int) -> T:
        if self._held is not None and self._held[0] == t:
            return self._held[1]
        item = _NONE
        if self._pending is not None:
            k, fut = self._pending
            self._pending = None
            if k == t:
                item = fut.result()  # an error making it is raised here, as inline
                self.prefetched += 1
            else:
                fut.exception()  # another batch: let it finish (one make at a time), drop it
        if item is _NONE:
            item = self.make(t)
        self._held = (t, item)
        if self._pool is not None and (self.last is None or t + 1 <= self.last):
            self._pending = (t + 1, self._pool.submit(self.make, t + 1))
        return item

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool, self._pending = None, None

    def __enter__(self) -> "Prefetched[T]":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
