"""The detectors that ship inside the package (``tasks/bundled``), by name.

``tasks/bundled/detectors.json`` is their manifest: each name's file, its sha256, the commands
that made it, its training record and its measured mAP. A design run's ``detector`` setting is a
shipped name or a checkpoint's path; "" is the first detector shipped ("street", the 699-step one
that runs made before names existed started from).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

from ..errors import InputError

BUNDLED = Path(__file__).resolve().parent / "bundled"
MANIFEST = BUNDLED / "detectors.json"
#: what ``detector = ""`` names: the first detector shipped
UNNAMED = "street"


@cache
def shipped_detectors() -> dict[str, dict]:
    """The manifest: each shipped detector's name and record (file, sha256, made_by, ...)."""
    return json.loads(MANIFEST.read_text())


def is_shipped(setting: str) -> bool:
    """Whether a ``detector`` setting names a shipped detector ("" included), not a path."""
    return setting == "" or setting in shipped_detectors()


def detector_file(setting: str) -> Path:
    """The checkpoint a ``detector`` setting names: a shipped detector's file, else the path."""
    if is_shipped(setting):
        return BUNDLED / shipped_detectors()[setting or UNNAMED]["file"]
    return Path(setting)


def check_detector_setting(setting: str) -> None:
    """One error where a ``detector`` setting names neither a shipped detector nor a file."""
    if not detector_file(setting).is_file():
        names = ", ".join(shipped_detectors())
        raise InputError(f"detector: no such file {setting} (shipped detectors: {names})")
