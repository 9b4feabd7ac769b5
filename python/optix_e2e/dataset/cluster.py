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

import functools
import hashlib
import socket
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from ..errors import RunError

# the engine's batch PSFs use every core of a worker's process unless told otherwise; a
# Dask worker with T threads gets T cores' worth of engine threads
WORKER_ENV = ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


# each worker thread's PSF buffers, reused from shard to shard (fresh arrays of a shard's
# size cost their page faults every time); released when a run ends
_buffers: dict[int, tuple] = {}
_buffers_lock = threading.Lock()


class ClusterError(RunError):
    """The Dask cluster cannot be reached or cannot run the dataset's shards."""


MAX_LOCAL_WORKERS = 256
PROTOCOLS = ("tcp", "tls", "ws", "wss", "ucx")  # dask.distributed's network protocols


def _check_address(spec: str, address: str, where: str) -> str:
    """``PROTOCOL://host:port`` with one of dask's protocols (a bare ``host:port`` is tcp),
    checked before any connection is tried: a port in 1..65535, an IPv4 address with octets up
    to 255 or a host name of letters, digits, dots, dashes and underscores."""
    import ipaddress
    import re

    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme not in PROTOCOLS:
        raise ClusterError(
            f"--dask {spec!r}: {where}: protocol {scheme!r} is not one of dask's "
            f"({', '.join(p + '://' for p in PROTOCOLS)})"
        )
    host, colon, port = rest.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host  # [IPv6]
    if not colon or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ClusterError(f"--dask {spec!r}: {where}: expected HOST:PORT with a port from 1 to 65535")
    try:
        ipaddress.ip_address(host)
    except ValueError:
        if re.fullmatch(r"\d+(\.\d+){3}", host) or not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,252}", host):
            raise ClusterError(f"--dask {spec!r}: {where}: {host!r} is not an IP address or a host name") from None
    return f"{scheme}://{rest}"


def parse_address(spec: str) -> tuple[str, "str | int"]:
    """``local:N`` -> ("local", N); ``PATH.json`` (a scheduler file, as ``dask scheduler
    --scheduler-file`` writes it) -> ("address", its address); anything else is a scheduler
    address (``tcp://host:8786``). Everything is checked here, before any connection."""
    import json

    spec = spec.strip()
    if spec.startswith("local:"):
        try:
            n = int(spec[6:])
        except ValueError:
            n = 0
        if not 1 <= n <= MAX_LOCAL_WORKERS:
            raise ClusterError(f"--dask {spec!r}: expected local:N with 1 <= N <= {MAX_LOCAL_WORKERS} workers")
        return "local", n
    if spec.endswith(".json"):
        from ..io import read_small_text

        try:
            info = json.loads(read_small_text(spec, what="scheduler file"))
        except FileNotFoundError:
            raise ClusterError(f"--dask {spec!r}: no such scheduler file") from None
        except (OSError, ValueError, RecursionError) as exc:
            raise ClusterError(f"--dask {spec!r}: not a scheduler file ({' '.join(str(exc).split())})") from None
        if not isinstance(info, dict) or not isinstance(info.get("address"), str):
            raise ClusterError(f'--dask {spec!r}: not a scheduler file (no "address" string)')
        return "address", _check_address(spec, info["address"], "its address")
    if not spec:
        raise ClusterError("--dask: empty address")
    return "address", _check_address(spec, spec, "address")


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
            cluster = LocalCluster(
                n_workers=value,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                env={v: "1" for v in WORKER_ENV},
            )
            client = Client(cluster, timeout=timeout_s)
        else:
            client = Client(value, timeout=timeout_s)
    except (OSError, TimeoutError, ValueError, RuntimeError, ImportError) as exc:
        if cluster is not None:
            cluster.close()
        raise ClusterError(f"--dask {spec!r}: cannot reach the scheduler ({exc})") from None
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _identity(out: str) -> dict:
    """What a worker must share with the client for the data to be the same: the dataset
    directory (its manifest's bytes, on shared storage) and the optix-e2e build."""
    from .. import __version__
    from .layout import sha256_file

    p = Path(out) / "manifest.json"
    return {
        "host": socket.gethostname(),
        "manifest": sha256_file(p) if p.is_file() else None,
        "optix_e2e": __version__,
        "engine": _engine_file_sha(),
    }


def _mismatch(mine: dict, expect: dict, out: str) -> str | None:
    """Why a worker of identity ``mine`` cannot write the client's dataset, or None."""
    if mine["manifest"] != expect["manifest"]:
        return (
            f"it does not see {Path(out) / 'manifest.json'} as the client wrote it: the output directory "
            f"must be on storage shared by the client and every worker, at the same path"
        )
    if (mine["optix_e2e"], mine["engine"]) != (expect["optix_e2e"], expect["engine"]):
        return (
            f"it runs another optix-e2e build (version {mine['optix_e2e']}, engine {mine['engine']}) than "
            f"the client ({expect['optix_e2e']}, {expect['engine']}); the data would not be the same"
        )
    return None


@functools.lru_cache(maxsize=1)
def _engine_file_sha() -> str:
    from .. import engine
    from .layout import sha256_file

    return sha256_file(Path(engine.extension_file()))[:16]


def _thread_buffers(man: dict) -> tuple:
    """This worker thread's shard buffers for ``man``'s shard shape (shards.shard_buffers)."""
    from .shards import shard_buffers

    key = threading.get_ident()
    shape = (
        man["settings"]["shard_size"],
        len(man["fields_deg"]),
        len(man["channels"]),
        man["psf_size"],
        man["sensor_size"],
    )
    with _buffers_lock:
        got = _buffers.get(key)
        if got is None or got[0] != shape:
            got = _buffers[key] = (shape, shard_buffers(man))
    return got[1]


def _release_buffers() -> int:
    with _buffers_lock:
        n = len(_buffers)
        _buffers.clear()
    return n


def run_shard(out: str, k: int, expect: dict) -> dict:
    """Dask task: compute shard ``k`` of the dataset in ``out`` (its manifest and designs
    read from there) and write it atomically; a shard already complete is left alone.
    ``expect``: the client's identity (:func:`_identity`), checked first on every task, so
    a worker that joins late with another view or build writes nothing."""
    from ..lens_design.sampling import read_designs_csv
    from .layout import read_manifest, shards_dir
    from .manifest import space_and_base
    from .shards import clean_stale, compute_shard, shard_complete, write_shard

    mine = _identity(out)
    why = _mismatch(mine, expect, out)
    if why:
        raise ClusterError(f"worker on {mine['host']}: {why}")
    root = Path(out)
    man = read_manifest(root)
    notes: list[str] = []
    if shard_complete(root, k, man, notes.append):
        return {"shard": k, "written": False, "n_ok": 0, "n_failed": 0, "notes": notes}
    space, base = space_and_base(man)
    designs = read_designs_csv(root / "designs.csv", space.names)
    sdir = shards_dir(root)
    if sdir.exists():
        clean_stale(sdir, k)
    psf_buf, sensor_buf = _thread_buffers(man)
    arrays, meta = compute_shard(
        k, man, designs, space, base, checked=True, psf_buffer=psf_buf, sensor_buffer=sensor_buf
    )
    written = write_shard(root, k, arrays, meta)
    return {"shard": k, "written": written, "n_ok": meta["n_ok"], "n_failed": meta["n_failed"], "notes": notes}


def run_shards(
    spec: str,
    out: Path,
    man: dict,
    pending: list[int],
    rep,
    bar=None,
    log: Callable[[str], None] = lambda m: None,
    wait_s: float = 120.0,
) -> None:
    """Run shards ``pending`` of the dataset in ``out`` as Dask tasks on ``spec``'s cluster,
    filling ``rep`` (a GenerateReport): shards written, designs ok and failed, and in
    ``rep.shard_errors`` the shards whose task failed (their error; run again to redo).
    ``wait_s``: how long to wait for a first worker to join."""
    from distributed import as_completed

    out = Path(out).resolve()
    size, n = man["settings"]["shard_size"], man["n_designs"]
    expect = _identity(str(out))
    with connect(spec, log) as client:
        try:  # a batch scheduler's workers may still be queued
            client.wait_for_workers(1, timeout=wait_s)
        except TimeoutError:
            raise ClusterError(f"--dask {spec!r}: no worker joined the cluster within {wait_s:g} s") from None
        # the workers there now are checked before any work; later ones by their first task
        views = client.run(_identity, str(out))
        bad = {w: _mismatch(v, expect, str(out)) for w, v in views.items()}
        bad = {w: why for w, why in bad.items() if why}
        if bad:
            w, why = sorted(bad.items())[0]
            raise ClusterError(
                f"Dask worker {w}" + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else "") + f": {why}"
            )
        log(
            f"Dask: {len(views)} worker(s) on {len({v['host'] for v in views.values()})} host(s), "
            f"{len(pending)} shard(s) to compute"
        )
        tag = hashlib.sha256(str(out).encode() + man["designs_csv_sha256"].encode()).hexdigest()[:10]
        futures = {
            client.submit(run_shard, str(out), k, expect, key=f"optix-shard-{tag}-{k:05d}", retries=1): k
            for k in pending
        }
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
            try:
                client.run(_release_buffers)
            except Exception:  # a worker gone meanwhile keeps nothing anyway
                pass
    rep.shards_written.sort()
    rep.shard_errors.sort(key=lambda e: e["shard"])
    from .shards import clean_temporaries

    # every task has ended: what a dead worker left of a shard that is now complete goes
    failed = {e["shard"] for e in rep.shard_errors}
    clean_temporaries(out, [k for k in pending if k not in failed])
