"""Held-out evaluations kept on disk (eval_*.json, detections_*.json in a run folder), so a run
started again after its trainings finished does not evaluate again. A file is reused only when
its key, a digest of everything that decides the figures besides the run's settings (PSFs,
vignetting, field heights, the processing's and the detector's weights, the number of samples),
matches, and its payload reads back as written; anything else is evaluated again."""

from __future__ import annotations

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
