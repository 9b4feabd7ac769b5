"""A dataset's missing shards as Dask tasks (dask.distributed), for ``optix dataset ...
--dask ADDRESS`` (docs/dataset.md, "On a Dask cluster").

The client samples the designs and writes the manifest as a local run does; each task
then computes one shard on a worker and writes it atomically into the same directory,
which every worker must see at the same path (a shared file system).  A worker that dies
mid-shard leaves at most a hidden temporary directory: the scheduler gives its task to
another worker, which computes the shard again, and the same seed gives the same bytes, so
the dataset is the one a single process writes (the same ``verify`` digest).
"""

from __future__ import annotations

import hashlib
import os
import socket
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

# the engine's batch PSFs use every core of a worker's process unless told otherwise; a
# Dask worker with T threads gets T cores' worth of engine threads
WORKER_ENV = ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


# each worker thread's PSF buffers, reused from shard to shard (fresh arrays of a shard's
# size cost their page faults every time)
_buffers = threading.local()


class ClusterError(RuntimeError):
    """The Dask cluster cannot be reached or cannot run the dataset's shards."""


def parse_address(spec: str) -> tuple[str, "str | int"]:
    """``local:N`` -> ("local", N); ``PATH.json`` (a scheduler file) -> ("file", PATH);
    anything else is a scheduler address (``tcp://host:8786``)."""
    spec = spec.strip()
    if spec.startswith("local:"):
        try:
            n = int(spec[6:])
        except ValueError:
            n = 0
        if n < 1:
            raise ClusterError(f"--dask {spec!r}: expected local:N with N >= 1 workers")
        return "local", n
    if spec.endswith(".json"):
        if not Path(spec).is_file():
            raise ClusterError(f"--dask {spec!r}: no such scheduler file")
        return "file", spec
    if not spec:
        raise ClusterError("--dask: empty address")
    return "address", spec


@contextmanager
def connect(spec: str, log: Callable[[str], None] = lambda m: None, timeout_s: float = 30.0) -> Iterator:
    """A ``distributed.Client`` for ``spec`` (see :func:`parse_address`); ``local:N`` starts
    a LocalCluster of N worker processes with 1 thread each, closed on exit."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise ClusterError(f"--dask needs dask.distributed ({exc})") from None
    kind, value = parse_address(spec)
    cluster = None
    try:
        if kind == "local":
            log(f"starting a local Dask cluster: {value} worker process(es), 1 thread each")
            cluster = LocalCluster(n_workers=value, threads_per_worker=1, processes=True, dashboard_address=None,
                                   env={v: "1" for v in WORKER_ENV})
            client = Client(cluster, timeout=timeout_s)
        elif kind == "file":
            client = Client(scheduler_file=value, timeout=timeout_s)
        else:
            client = Client(value, timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise ClusterError(f"--dask {spec!r}: cannot reach the scheduler ({exc})") from None
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _worker_view(out: str, manifest_sha: str) -> dict:
    """Runs on each worker: does it see the dataset directory, and which optix-e2e?"""
    from .. import __version__
    from .layout import sha256_file

    p = Path(out) / "manifest.json"
    sees = p.is_file() and sha256_file(p) == manifest_sha
    return {"host": socket.gethostname(), "sees_manifest": sees, "optix_e2e": __version__,
            "engine": _engine_file_sha()}


def _engine_file_sha() -> str:
    from .. import _engine

    return _sha_of(Path(_engine.__file__))


def _sha_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def run_shard(out: str, k: int) -> dict:
    """Dask task: compute shard ``k`` of the dataset in ``out`` (its manifest and designs
    read from there) and write it atomically; a shard already complete is left alone."""
    from ..design.sampling import read_designs_csv
    from .generate import _clean_stale, _complete, compute_shard, write_shard
    from .layout import aligned_empty, read_manifest, shards_dir
    from .manifest import space_and_base

    root = Path(out)
    man = read_manifest(root)
    notes: list[str] = []
    if _complete(root, k, man, notes.append):
        return {"shard": k, "written": False, "n_ok": 0, "n_failed": 0, "notes": notes}
    space, base = space_and_base(man)
    designs = read_designs_csv(root / "designs.csv", space.names)
    sdir = shards_dir(root)
    if sdir.exists():
        _clean_stale(sdir, k)
    lead = (man["settings"]["shard_size"], len(man["fields_deg"]), len(man["channels"]))
    shapes = (lead + (man["psf_size"],) * 2, lead + (man["sensor_size"],) * 2)
    if getattr(_buffers, "shapes", None) != shapes:
        _buffers.shapes, _buffers.arrays = shapes, tuple(aligned_empty(sh, np.float32) for sh in shapes)
    psf_buf, sensor_buf = _buffers.arrays
    arrays, meta = compute_shard(k, man, designs, space, base, checked=True, psf_buffer=psf_buf,
                                 sensor_buffer=sensor_buf)
    written = write_shard(root, k, arrays, meta)
    return {"shard": k, "written": written, "n_ok": meta["n_ok"], "n_failed": meta["n_failed"],
            "seconds": meta["seconds"], "worker": f"{socket.gethostname()}:{os.getpid()}", "notes": notes}


def run_shards(spec: str, out: Path, man: dict, pending: list[int], rep, bar=None,
               log: Callable[[str], None] = lambda m: None) -> None:
    """Run shards ``pending`` of the dataset in ``out`` as Dask tasks on ``spec``'s cluster,
    filling ``rep`` (a GenerateReport): shards written, designs ok and failed, and in
    ``rep.shard_errors`` the shards whose task failed (their error; run again to redo)."""
    from distributed import as_completed

    from .layout import sha256_file

    out = Path(out).resolve()
    size, n = man["settings"]["shard_size"], man["n_designs"]
    with connect(spec, log) as client:
        views = client.run(_worker_view, str(out), sha256_file(out / "manifest.json"))
        if not views:
            raise ClusterError(f"--dask {spec!r}: the cluster has no workers")
        blind = sorted(w for w, v in views.items() if not v["sees_manifest"])
        if blind:
            raise ClusterError(f"Dask worker(s) {', '.join(blind)} do not see {out / 'manifest.json'}: the "
                               f"output directory must be on storage shared by the client and every worker, "
                               f"at the same path")
        mine = {"optix_e2e": __import__("optix_e2e").__version__, "engine": _engine_file_sha()}
        other = sorted(w for w, v in views.items() if (v["optix_e2e"], v["engine"]) != tuple(mine.values()))
        if other:
            raise ClusterError(f"Dask worker(s) {', '.join(other)} run another optix-e2e build than this client "
                               f"({mine}); the data would not be the same")
        log(f"Dask: {len(views)} worker(s) on {len({v['host'] for v in views.values()})} host(s), "
            f"{len(pending)} shard(s) to compute")
        tag = hashlib.sha256(str(out).encode() + man["designs_csv_sha256"].encode()).hexdigest()[:10]
        futures = {client.submit(run_shard, str(out), k, key=f"optix-shard-{tag}-{k:05d}", retries=1): k
                   for k in pending}
        try:
            for fut in as_completed(futures):
                k = futures[fut]
                try:
                    r = fut.result()
                except Exception as exc:  # the task's own error, or KilledWorker
                    rep.shard_errors.append({"shard": k, "error": f"{type(exc).__name__}: {exc}"})
                    log(f"shard {k}: {type(exc).__name__}: {exc}")
                else:
                    for note in r["notes"]:
                        log(note)
                    if r["written"]:
                        rep.shards_written.append(k)
                    rep.n_ok += r["n_ok"]
                    rep.n_failed += r["n_failed"]
                if bar is not None:
                    bar.update(min(n, (k + 1) * size) - k * size)
                    bar.set_postfix(failed=rep.n_failed, errors=len(rep.shard_errors), refresh=False)
        finally:
            client.cancel(list(futures))
    rep.shards_written.sort()
    rep.shard_errors.sort(key=lambda e: e["shard"])
    from .generate import clean_temporaries

    # every task has ended: what a dead worker left of a shard that is now complete goes
    failed = {e["shard"] for e in rep.shard_errors}
    clean_temporaries(out, [k for k in pending if k not in failed])
