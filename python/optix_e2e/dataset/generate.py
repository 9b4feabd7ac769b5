"""Generate a PSF dataset: sample designs from a parameter space, compute RGB PSFs at K
field positions with the engine, write them shard by shard (docs/dataset.md).

Resumable: finished shards that pass verify's checks are skipped; an interrupted one is
redone, and so is a damaged one (moved aside first).  Deterministic: the
designs come from the seed, and the engine's batch PSFs do not depend on the thread count,
so the same command gives byte-identical arrays.  Shards are independent units: processes
may run disjoint shard ranges (``shards=range(a, b)``) into the same directory, or into
separate directories that :func:`optix_e2e.dataset.merge.merge` combines.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError
from ..lens import Lens
from ..lens_design.space import ParameterSpace, load_space
from .layout import shards_dir
from .manifest import prepare
from .settings import DatasetSettings
from .shards import clean_stale, compute_shard, shard_buffers, shard_complete, write_shard


@dataclass
class GenerateReport:
    out: str
    n_designs: int
    n_shards: int
    shards_written: list = field(default_factory=list)
    shards_skipped: list = field(default_factory=list)
    n_ok: int = 0  # designs written by this run
    n_failed: int = 0  # designs that failed in the engine in this run
    shard_errors: list = field(default_factory=list)  # --dask: shards whose task failed, with the error
    seconds: float = 0.0

    @property
    def designs_per_s(self) -> float:
        return (self.n_ok + self.n_failed) / self.seconds if self.seconds > 0 else 0.0

    def to_json(self) -> dict:
        return {**asdict(self), "designs_per_s": self.designs_per_s}


def parse_shard_range(spec: str | None, n_shards: int) -> range:
    """``"a:b"`` (b exclusive; either side may be empty) or ``"k"`` -> a range of shards."""
    if not spec:
        return range(n_shards)
    try:
        if ":" in spec:
            a, b = spec.split(":", 1)
            r = range(int(a) if a else 0, int(b) if b else n_shards)
        else:
            r = range(int(spec), int(spec) + 1)
    except ValueError:
        raise InputError(f"--shards {spec!r}: expected A:B or K (integers)") from None
    if r.start < 0 or r.stop > n_shards or r.start >= r.stop:
        raise InputError(f"--shards {spec!r}: the dataset has shards 0..{n_shards - 1}")
    return r


def generate(
    space_spec: "str | Path",
    n: int,
    seed: int,
    out: "str | Path",
    settings: DatasetSettings | None = None,
    shards: str | None = None,
    progress: bool = True,
    log: Callable[[str], None] = lambda m: None,
    dask: str | None = None,
) -> GenerateReport:
    """Create or finish the dataset in ``out`` (see the module docstring).  ``dask``: run
    the missing shards as tasks on a Dask cluster instead (``local:N``, a scheduler address
    or a scheduler file; :mod:`.cluster`); ``out`` must then be on storage every worker sees."""
    s = settings or DatasetSettings()
    s.check()
    if n < 1:
        raise InputError(f"n must be >= 1, got {n}")
    out = Path(out)
    if dask is not None:  # a malformed address is refused before anything is written
        from .cluster import parse_address

        parse_address(dask)
    space, base = load_space(space_spec)
    # before anything is written: auto fields take at most the largest K they try
    from ..accuracy.auto import K_FIELDS

    s.check_memory(
        n, s.n_fields or max(K_FIELDS), len(base.rgb_channels("rgb" if s.channels == "auto" else s.channels))
    )
    man, designs = prepare(out, space, base, n, seed, s, log)
    n_shards = man["n_shards"]
    todo = parse_shard_range(shards, n_shards)
    rep = GenerateReport(out=str(out), n_designs=n, n_shards=n_shards)
    pending = [k for k in todo if not shard_complete(out, k, man, log)]
    rep.shards_skipped = [k for k in todo if k not in pending]
    if rep.shards_skipped:
        log(f"{len(rep.shards_skipped)} shard(s) already complete, skipped")
    total = sum(min(n, (k + 1) * s.shard_size) - k * s.shard_size for k in pending)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="design", desc="dataset", dynamic_ncols=True)
    t0 = time.perf_counter()
    try:
        if dask is not None and pending:
            from .cluster import run_shards

            run_shards(dask, out, man, pending, rep, bar, log)
        else:
            _run_here(out, man, designs, space, base, pending, rep, bar)
    finally:
        rep.seconds = time.perf_counter() - t0
        if bar is not None:
            bar.close()
    return rep


def _run_here(
    out: Path,
    man: dict,
    designs: np.ndarray,
    space: ParameterSpace,
    base: Lens,
    pending: list,
    rep: GenerateReport,
    bar,
) -> None:
    """Compute and write shards ``pending`` in this process, filling ``rep``."""
    sdir = shards_dir(out)
    failed = {"n": 0}

    def on_batch(done, nfail):
        failed["n"] += nfail
        if bar is not None:
            bar.update(done)
            bar.set_postfix(failed=failed["n"], refresh=False)

    def finish(job):
        k, meta, fut = job
        if fut.result():
            rep.shards_written.append(k)
        rep.n_ok += meta["n_ok"]
        rep.n_failed += meta["n_failed"]

    # a writer thread stores shard k while the engine (which releases the GIL) computes
    # shard k + 1; at most one shard waits, and an interruption lets its write finish
    writing = None
    buffers = [None, None]  # the shard being computed and the one being written: (psf, sensor)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="shard-writer") as pool:
        for n_done, k in enumerate(pending):
            if sdir.exists():
                clean_stale(sdir, k)
            if buffers[n_done % 2] is None and len(pending) > 1:
                buffers[n_done % 2] = shard_buffers(man)
            psf_buf, sensor_buf = buffers[n_done % 2] or (None, None)
            arrays, meta = compute_shard(
                k,
                man,
                designs,
                space,
                base,
                on_batch=on_batch,
                psf_buffer=psf_buf,
                sensor_buffer=sensor_buf,
                checked=True,
            )
            if writing is not None:
                finish(writing)
            writing = (k, meta, pool.submit(write_shard, out, k, arrays, meta))
        if writing is not None:
            finish(writing)
