"""Held-out evaluations kept on disk (eval_*.json, detections_*.json in a run folder), so a run
started again after its trainings finished does not evaluate again. A file is reused only when
its key matches and its payload reads back as written; anything else is evaluated again.

The key (``evaluation_key``) is a sha256 of everything that decides the figures besides the run's settings
(which config.json fixes for the folder):

* the camera: its PSFs, vignetting and field heights (exact or surrogate optics), the
  processing's weights and state (the ISP's state_dict; the detector's too for detection) and,
  for detection, the lens's f-number;
* the sensor (``sensor_digest``): its preset (every field: pixel pitch, full well, read noise,
  gain, black level, exposure, f-number and radiance scale of the calibration, CFA, QE curves,
  ...), whether it draws noise, and its state_dict;
* the held-out samples (``samples_digest``, computed once per evaluation): each sample's name,
  position, scene tensor, target, offset on the sensor, noise seed (and for detection its
  object lights, size, radius and level), in order;
* the code (``code_digest``, computed once per process): the package's version and every .py
  file under optix_e2e (its path and bytes), so a change to the renderer, the sensor model, the
  metrics or the evaluation itself evaluates again;
* a tag naming the evaluation ("perfect-optics", the detection's f-number).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from pathlib import Path

import torch

from ..io import write_json_atomic


def digest(header: str, tensors) -> str:
    """sha256 of ``header`` and the bytes of each tensor, in order."""
    h = hashlib.sha256(header.encode())
    for t in tensors:
        h.update(torch.as_tensor(t).detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _feed(h, value) -> None:
    """Feed ``value`` to the hash ``h``: tensors by dtype, shape and bytes, containers
    recursively (dicts by sorted key), dataclasses field by field, anything else by repr."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous()
        h.update(f"tensor {t.dtype} {tuple(t.shape)}|".encode())
        h.update(t.numpy().tobytes())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(f"{type(value).__name__}(".encode())
        for f in dataclasses.fields(value):
            h.update(f"{f.name}=".encode())
            _feed(h, getattr(value, f.name))
        h.update(b")")
    elif isinstance(value, dict):
        h.update(b"{")
        for k in sorted(value, key=str):
            h.update(f"{k!r}:".encode())
            _feed(h, value[k])
        h.update(b"}")
    elif isinstance(value, (list, tuple)):
        h.update(f"{type(value).__name__}[".encode())
        for v in value:
            _feed(h, v)
        h.update(b"]")
    else:
        h.update(f"{value!r}|".encode())


def samples_digest(samples) -> str:
    """sha256 of the held-out samples, every field of each in order (scene, target, offset,
    position, noise seed, ...): another set, or the same set drawn differently, has another."""
    h = hashlib.sha256(f"samples n={len(samples)}|".encode())
    for s in samples:
        _feed(h, s)
    return h.hexdigest()


def sensor_digest(sensor) -> str:
    """sha256 of a camera's sensor stage: its class, preset (all fields), noise switch and state_dict."""
    h = hashlib.sha256(f"sensor {type(sensor).__name__}|".encode())
    _feed(h, getattr(sensor, "preset", None))
    _feed(h, {"noise": getattr(sensor, "noise", None)})
    _feed(h, dict(sensor.state_dict()))
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """sha256 of the package's version and its .py source files (relative path and bytes,
    sorted by path); computed once per process."""
    import optix_e2e

    root = Path(optix_e2e.__file__).resolve().parent
    h = hashlib.sha256(f"optix_e2e {getattr(optix_e2e, '__version__', '')}|".encode())
    for path in sorted(root.rglob("*.py")):
        try:
            data = path.read_bytes()
        except OSError:  # gone since the listing (an editor's temporary file): not part of the code
            continue
        h.update(f"{path.relative_to(root).as_posix()}|".encode())
        h.update(data)
    return h.hexdigest()


def evaluation_key(what: str, *, samples: str, sensor: str, tensors) -> str:
    """An evaluation's cache key (see the module doc): ``what`` (a tag, counts), the samples'
    and the sensor's digests, the code's, and the camera's ``tensors`` (optics, processing)."""
    header = json.dumps({"what": what, "samples": samples, "sensor": sensor, "code": code_digest()}, sort_keys=True)
    return digest(header, tensors)


def read(path: Path, key: str) -> dict | None:
    """The cached evaluation at ``path`` if its key is ``key`` (None: absent, stale or
    unreadable). The caller checks the payload and evaluates again if it is damaged."""
    try:
        cached = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    if not (isinstance(cached, dict) and cached.get("key") == key):
        return None
    return cached


def write(path: Path, key: str, wall_s: float, **payload) -> None:
    write_json_atomic(path, {"key": key, "wall_s": wall_s, **payload})
