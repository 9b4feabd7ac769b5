"""On-disk layout of a dataset directory and the atomic writes that keep it consistent.

```
DIR/manifest.json          settings, space, base lens, seed, sampling summary, statistics
DIR/designs.csv            every sampled design (index, parameter values)
DIR/shards/00000/          one shard: designs [k*shard_size, (k+1)*shard_size)
    design.npy             (m,) int64 global indices of the designs that succeeded
    params.npy             (m, P) float64 parameter values
    psf.npy                (m, K, C, S, S) float32 super-resolved PSFs, unit sum per channel
    psf_sensor.npy         (m, K, C, s, s) float32 the same integrated over sensor pixels
    relative_illumination.npy  (m, K, C) float64
    image_distance.npy     (m,) float64 last vertex to image plane after refocusing (mm)
    energy_in_window.npy   (m, K, C) float32 fraction of the transmitted energy inside the window
    shard.json             failures with reasons, the engine's warnings per design, shapes,
                           CRC-32 of every .npy file
```

A shard is written into a hidden temporary directory and renamed into place when complete,
so a shard directory that exists is whole; an interrupted shard leaves only a hidden
temporary directory, removed and redone by the next run.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import zlib
from pathlib import Path

import numpy as np

from ..errors import InputError

FORMAT = "optix-psf-dataset/1"
ARRAYS = ("design", "params", "psf", "psf_sensor", "relative_illumination", "image_distance", "energy_in_window")
VALUES = ARRAYS[1:]  # the per-design data, after the design index

# (fsync_dir, the atomic writes, read_small_text and claim_out_dir live in optix_e2e.io)


class DatasetError(InputError):
    """A dataset directory that does not match the request, or is damaged; the message
    names the file and what is wrong."""


def shard_name(k: int) -> str:
    return f"{k:05d}"


def shards_dir(root: Path) -> Path:
    return Path(root) / "shards"


def sha256_file(path: Path, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def crc32(data, crc: int = 0) -> int:
    """CRC-32 (zlib's) of a bytes-like object, continuing from ``crc``: the engine's
    (crc32fast, ~10 GB/s, GIL released) for large buffers, zlib's for small ones."""
    if len(data) < 1 << 16:
        return zlib.crc32(data, crc)
    from .. import engine

    return engine.crc32(np.frombuffer(data, np.uint8), crc=crc)


def crc32_file(path: Path, chunk: int = 1 << 22) -> str:
    """CRC-32 of a file (hex): the shards' checksums, cheap enough (GB/s) to check every
    shard on every read; the dataset digest of ``verify`` is a sha256."""
    crc = 0
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            crc = crc32(b, crc)
    return f"{crc:08x}"


ALIGN = 4096  # direct I/O: buffer addresses, file offsets and lengths in these units
DIRECT_MIN_BYTES = 1 << 20


def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialized C-contiguous array whose data starts on an ``ALIGN`` boundary (so
    :func:`save_npy` can write it with direct I/O)."""
    dtype = np.dtype(dtype)
    n = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = np.empty(n + ALIGN, np.uint8)
    off = (-raw.ctypes.data) % ALIGN
    return raw[off : off + n].view(dtype).reshape(shape)


def npy_header(arr: np.ndarray, pad_to: int = 64) -> bytes:
    """The .npy version 1.0 header of ``arr`` (magic, length, dict), padded with spaces to a
    multiple of ``pad_to`` bytes as the format allows; numpy reads any such header."""
    d = np.lib.format.header_data_from_array_1_0(arr)
    text = "{" + "".join(f"'{k}': {d[k]!r}, " for k in sorted(d)) + "}"
    n = 10 + len(text) + 1
    text += " " * ((-n) % pad_to) + "\n"
    if len(text) > 65535:
        raise InputError(f"npy header of {len(text)} bytes")
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode("latin1")


def _write_all(fd: int, mv: memoryview) -> None:
    while len(mv):
        mv = mv[os.write(fd, mv) :]


def save_npy(path: Path, arr: np.ndarray) -> str:
    """Write ``arr`` as a .npy file, synced to disk; returns its CRC-32 (hex).

    A large array whose data is ``ALIGN``-aligned goes to disk with direct I/O (O_DIRECT):
    its header is padded to ``ALIGN`` bytes, and the data goes from the array's own pages to
    the device without a copy into the page cache.  A dataset writes GBs it will not read
    back soon: buffered, each MB costs the kernel fresh page-cache pages (in a VM, ~2.5 ms
    of CPU per MB here, taken from the engine's two cores); direct, almost nothing.  Where
    the file system refuses direct I/O (tmpfs), or for small or unaligned arrays, it writes
    through the page cache; the file's bytes are the same either way for a given header."""
    arr = np.ascontiguousarray(arr)
    data = memoryview(arr.reshape(-1).view(np.uint8)) if arr.size else memoryview(b"")
    direct = getattr(os, "O_DIRECT", 0) and arr.nbytes >= DIRECT_MIN_BYTES and arr.ctypes.data % ALIGN == 0
    header = npy_header(arr, ALIGN if direct else 64)
    crc = crc32(data, crc32(header))
    if direct:
        try:
            _save_direct(path, header, data)
            return f"{crc:08x}"
        except OSError as exc:
            if exc.errno != errno.EINVAL:
                raise
    with open(path, "wb") as f:
        f.write(header)
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    return f"{crc:08x}"


def _save_direct(path: Path, header: bytes, data: memoryview) -> None:
    """Header (one ``ALIGN`` block) and the aligned body with O_DIRECT, the tail (under one
    block) buffered; then fsync (file size and metadata).  EINVAL: no direct I/O here."""
    import fcntl  # POSIX only, like O_DIRECT itself

    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_DIRECT, 0o644)
    try:
        hbuf = aligned_empty((len(header),), np.uint8)
        hbuf[:] = np.frombuffer(header, np.uint8)
        _write_all(fd, memoryview(hbuf))
        body = len(data) - len(data) % ALIGN
        _write_all(fd, data[:body])
        if body < len(data):
            fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_DIRECT)
            _write_all(fd, data[body:])
        os.fsync(fd)
    finally:
        os.close(fd)


# Entries that say where a manifest's inputs were read from, not what they are: the path of
# the space's TOML differs between installs (a bundled space under another venv) and copies
# of the same file, so a dataset resumes, merges and compares across them.
_WHERE_FROM = {"space": ("source",)}


def _comparable(man: dict, key: str) -> str:
    v = man.get(key)
    if isinstance(v, dict) and key in _WHERE_FROM:
        v = {k: x for k, x in v.items() if k not in _WHERE_FROM[key]}
    return json.dumps(v, sort_keys=True)


def differing_keys(a: dict, b: dict, keys) -> list[str]:
    """The keys among ``keys`` whose values differ between two manifests (JSON-equal
    values are equal; where a space was read from is not compared, only what it holds)."""
    return sorted(k for k in keys if _comparable(a, k) != _comparable(b, k))


def read_manifest(root: "str | Path") -> dict:
    """``root``'s manifest.json, which must be a manifest of this format with the keys
    readers use well-formed (:func:`check_manifest`)."""
    path = Path(root) / "manifest.json"
    man = read_json(path, "manifest")
    if not isinstance(man, dict) or man.get("format") != FORMAT:
        raise DatasetError(f"{path}: not a {FORMAT} manifest")
    check_manifest(man, path)
    return man


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def check_manifest(man: dict, path) -> None:
    """DatasetError naming the first key of ``man`` that readers need and that is missing
    or malformed (counts, sizes, fields, channels, parameters and their statistics)."""

    def bad(key, what):
        raise DatasetError(f"{path}: damaged manifest: {key} {what}")

    def count(key, v, lo=1):
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= lo):
            bad(key, f"must be an integer >= {lo}, got {v!r}")
        return v

    def numbers(key, v, n=None):
        if not (isinstance(v, list) and v and all(_is_number(x) for x in v)) or (n is not None and len(v) != n):
            bad(key, f"must be a list of {n if n is not None else 'some'} finite numbers, got {str(v)[:60]}")

    settings = man.get("settings")
    if not isinstance(settings, dict):
        bad("settings", "missing or not an object")
    n = count("n_designs", man.get("n_designs"))
    size = count("settings.shard_size", settings.get("shard_size"))
    if count("n_shards", man.get("n_shards")) != -(-n // size):
        bad("n_shards", f"is {man['n_shards']}, but {n} designs in shards of {size} make {-(-n // size)}")
    count("psf_size", man.get("psf_size"))
    count("sensor_size", man.get("sensor_size"))
    numbers("fields_deg", man.get("fields_deg"))
    channels = man.get("channels")
    if not (
        isinstance(channels, list)
        and channels
        and all(
            isinstance(c, list)
            and c
            and all(isinstance(w, list) and len(w) == 2 and all(map(_is_number, w)) for w in c)
            for c in channels
        )
    ):
        bad("channels", f"must be a list of channels of [wavelength, weight] pairs, got {str(channels)[:60]}")
    names = man.get("channel_names")
    if not (isinstance(names, list) and len(names) == len(channels) and all(isinstance(x, str) for x in names)):
        bad("channel_names", f"must name the {len(channels)} channels, got {str(names)[:60]}")
    space = man.get("space")
    params = space.get("parameters") if isinstance(space, dict) else None
    if not (
        isinstance(params, list)
        and params
        and all(
            isinstance(q, dict)
            and isinstance(q.get("name"), str)
            and _is_number(q.get("min"))
            and _is_number(q.get("max"))
            for q in params
        )
    ):
        bad("space.parameters", "must be a list of parameters with a name, min and max")
    numbers("param_mean", man.get("param_mean"), len(params))
    numbers("param_std", man.get("param_std"), len(params))
    base = man.get("base_lens")
    if not isinstance(base, dict):
        bad("base_lens", f"must be the base lens's prescription (an object), got {str(base)[:60]}")
    from ..lens.glass import GlassError
    from ..lens.prescription import PrescriptionError, resolve_prescription

    try:
        resolve_prescription(base, "base_lens")
    except (PrescriptionError, GlassError) as exc:
        bad("base_lens", f"is not a lens prescription ({exc})")
    sha = man.get("designs_csv_sha256")
    if sha is not None and not (isinstance(sha, str) and len(sha) == 64):
        bad("designs_csv_sha256", f"is not a sha256 hex digest: {str(sha)[:70]}")


def read_json(path: Path, what: str) -> dict:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing {what}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise DatasetError(f"{path}: unreadable {what} ({type(exc).__name__}: {exc})") from None
