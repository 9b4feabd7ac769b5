"""What a design run's file settings hold, so that a run resumes wherever its inputs now lie.

``config.json`` records the pre-trained detector, the software ISP and the image folder by
absolute path (``config.PATH_SETTINGS``). A run folder copied to another machine (the GPU
machine's copy of the tree, a fresh clone) or an input moved next to it names another path for
the same file. ``inputs.json`` beside ``config.json`` records each one's content fingerprint when
the run is made; on resume a setting whose path changed counts as the same where the new path
holds what the old one held (by the recorded fingerprint, or, for a run made before
``inputs.json``, by the old path's file where it still exists); a setting whose path is the same
but whose content changed since (an --images folder edited between a kill and its resume) is not
the same run.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ..dataset.layout import sha256_file
from ..io import write_json_atomic
from ..tasks.shipped_detectors import detector_file

INPUTS_FILE = "inputs.json"


def fingerprint(value: str) -> str | None:
    """sha256 of the file ``value`` names, or of a folder's files (their paths relative to it
    and their own sha256, sorted); None where nothing readable is there."""
    p = Path(value)
    try:
        if p.is_file():
            return "sha256:" + sha256_file(p)
        if p.is_dir():
            h = hashlib.sha256()
            for f in sorted(x for x in p.rglob("*") if x.is_file()):
                h.update(f"{f.relative_to(p).as_posix()}\0{sha256_file(f)}\n".encode())
            return "folder-sha256:" + h.hexdigest()
    except OSError:
        return None
    return None


def located(key: str, value: str) -> str:
    """Where setting ``key``'s ``value`` lies: a shipped detector's name is its bundled file."""
    return str(detector_file(value)) if key == "detector" else value


def record(out: Path, settings: dict, keys) -> None:
    """Write ``out``/inputs.json: each set path setting's path and fingerprint."""
    rec = {
        k: {"path": settings[k], "fingerprint": fingerprint(located(k, settings[k]))} for k in keys if settings.get(k)
    }
    write_json_atomic(out / INPUTS_FILE, rec)


def recorded(out: Path, key: str, path: str) -> str | None:
    """The fingerprint ``inputs.json`` recorded for setting ``key`` at ``path`` (None where it
    recorded none for that path, or is unreadable)."""
    try:
        rec = json.loads((out / INPUTS_FILE).read_text())
    except (OSError, ValueError, RecursionError):
        return None
    entry = rec.get(key) if isinstance(rec, dict) else None
    if isinstance(entry, dict) and entry.get("path") == path and isinstance(entry.get("fingerprint"), str):
        return entry["fingerprint"]
    return None


def same_content(out: Path, key: str, old: str, new: str) -> bool:
    """Whether the path setting ``key``, ``old`` when the run was made, ``new`` now, names the
    same content: the fingerprint ``inputs.json`` recorded for ``old`` (or, without one, the
    old path's own where it exists) equals the new path's."""
    if not old or not new:
        return False
    was = recorded(out, key, old) or fingerprint(located(key, old))
    return was is not None and was == fingerprint(located(key, new))


def content_changed(out: Path, key: str, path: str) -> bool:
    """Whether the file or folder ``path`` of setting ``key`` no longer holds what ``inputs.json``
    recorded for that same path (False where nothing was recorded for it)."""
    was = recorded(out, key, path)
    return was is not None and fingerprint(located(key, path)) != was
