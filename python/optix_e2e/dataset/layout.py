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

import hashlib
import json
import os
import zlib
from pathlib import Path

FORMAT = "optix-psf-dataset/1"
ARRAYS = ("design", "params", "psf", "psf_sensor", "relative_illumination", "image_distance",
          "energy_in_window")
VALUES = ARRAYS[1:]  # the per-design data, after the design index


class DatasetError(RuntimeError):
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


def crc32_file(path: Path, chunk: int = 1 << 22) -> str:
    """CRC-32 of a file (hex): the shards' checksums, cheap enough (GB/s) to check every
    shard on every read; the dataset digest of ``verify`` is a sha256."""
    crc = 0
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            crc = zlib.crc32(b, crc)
    return f"{crc:08x}"


class Crc32Writer:
    """A write-only file wrapper that keeps the CRC-32 of what passes through."""

    def __init__(self, f):
        self.f, self.crc = f, 0

    def write(self, b) -> int:
        self.crc = zlib.crc32(b, self.crc)
        return self.f.write(b)

    @property
    def hex(self) -> str:
        return f"{self.crc:08x}"


def fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_json_atomic(path: Path, obj) -> None:
    """Write JSON to a temporary file, fsync, rename over ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(obj, f, indent=2, allow_nan=False)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)


def differing_keys(a: dict, b: dict, keys) -> list[str]:
    """The keys among ``keys`` whose values differ between two manifests (JSON-equal
    values are equal)."""
    return sorted(k for k in keys if json.dumps(a.get(k), sort_keys=True) != json.dumps(b.get(k), sort_keys=True))


def read_json(path: Path, what: str) -> dict:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing {what}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: unreadable {what} ({exc})") from None
