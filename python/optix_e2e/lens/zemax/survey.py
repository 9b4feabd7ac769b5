"""Import rate of a folder of real .zmx files (``optix lens survey``; docs/zemax.md).

For every file: does it import (lenient: unknown keywords listed, not fatal), does it
trace (paraxial EFL, plus a real chief ray at the largest field and a real marginal ray
on axis), and for catalog files, is the EFL within 1 % of the nominal focal length in
the NAME or NOTE line (``f = 35 mm``, ``22.5mm FL``, ``Infinite Conjugate 200`` ...)?

The target set is the rotationally symmetric refractive files: every surface STANDARD,
EVENASPH or ODDASPHE, no mirror, no coordinate break or tilt/decenter.  A file outside it
should be refused with an error naming its feature; the survey counts the reasons.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ...engine import EngineError
from ..model import Lens
from ..text import display_name, printable
from .common import ZemaxError
from .reader import _decode

MAX_FILE_BYTES = 16 << 20  # real .zmx files are kilobytes; a larger one is not read into memory

TARGET_TYPES = {"STANDARD", "EVENASPH", "ODDASPHE"}
EFL_TOLERANCE = 0.01

_NUM = r"(-?\d+(?:\.\d+)?)"
#: Nominal focal length in catalog NAME/NOTE text, most specific first.
_FL_PATTERNS = [
    re.compile(p, re.IGNORECASE)
    for p in (
        rf"\b(?:f|efl)\s*=\s*{_NUM}",  # f = 35mm, efl=10.0mm, f=11.00mm
        rf"\bEFL\s+{_NUM}",  # EFL 2.01
        rf"{_NUM}\s*(?:mm)?\s*FL\b",  # 22.5mm FL, -100mm FL, 18.4FL
        rf"\bX\s*{_NUM}\s*(?:mm\s*)?FL\b",  # 12.5 DIA X 25 FL, 25.4 SQ X -50 FL
        # Edmund stock names: LENS ACH 25 X 200, LENS PCX GE 25 X 40, LENS PCX ZNSE 25.4 X 50.8MM
        rf"\bLENS\s+(?:[A-Z0-9-]+\s+){{1,3}}[\d.]+\s*(?:MM)?\s*X\s*{_NUM}(?![\d.])",
        rf"\bInfinite(?:\s+Conjugate)?\s+{_NUM}(?![\d.])",  # Thorlabs achromats: Infinite Conjugate 200
    )
]
_PART_FL = re.compile(r"^ACA?\d{3}-(\d{3})\b")  # Thorlabs achromats: AC254-200-B -> 200 mm


@dataclass
class FileResult:
    file: str
    target: bool  # rotationally symmetric refractive (see module doc)
    features: str  # what puts it outside the target set ("" inside)
    imported: bool
    traced: bool
    efl_mm: float | None
    nominal_mm: float | None
    efl_ok: bool | None  # |EFL / nominal - 1| <= 1 %; None without a nominal value
    error: str  # one line: the reader's or the trace's error


def nominal_focal_length(text: str) -> float | None:
    """The focal length a catalog file's NAME or NOTE lines state, or None."""
    lines = [
        ln.split(None, 1)[1]
        for ln in text.splitlines()
        if ln.startswith(("NAME ", "NOTE ")) and len(ln.split(None, 1)) > 1
    ]
    for pat in _FL_PATTERNS:
        for ln in lines:
            m = pat.search(ln)
            if m:
                return float(m.group(1))
    for ln in lines[:1]:
        m = _PART_FL.match(ln.strip())
        if m:
            return float(m.group(1))
    return None


def _features(text: str) -> list[str]:
    """What takes the file outside the target set, from a plain scan of its lines."""
    found = []
    for ln in text.splitlines():
        tok = ln.split()
        if not tok:
            continue
        if tok[0] == "TYPE" and len(tok) > 1 and tok[1] not in TARGET_TYPES:
            found.append(tok[1])
        elif tok[0] == "GLAS" and len(tok) > 1 and tok[1].upper() == "MIRROR":
            found.append("MIRROR")
        elif tok[0] in ("SCBD", "TILT", "DECX", "DECY") and any(_nonzero(v) for v in tok[2:] or tok[1:]):
            found.append("tilt/decenter")
        elif tok[0] == "MODE" and tok[1:2] != ["SEQ"]:
            found.append("non-sequential")
    return sorted(set(found))


def _nonzero(v: str) -> bool:
    try:
        return float(v) != 0
    except ValueError:
        return False


def _trace_check(lens) -> str:
    """'' when the paraxial EFL is finite and two real rays reach the image: the chief ray
    of the largest field and an on-axis marginal ray, at the largest pupil fraction
    (0.99 down to 0.25) that the clear apertures pass (catalog files often give an ENPD
    wider than the lens's clear aperture); else why not."""
    par = lens.paraxial()
    if not math.isfinite(par["efl_mm"]):
        return ""  # afocal (a window): imported, EFL infinite, nothing to focus

    def reaches(field, py):
        r = lens.trace_field(field, np.array([0.0]), np.array([py]))
        return int(r["status"][0]) == 0 and bool(np.all(np.isfinite(r["position"][0])))

    if not reaches(lens.max_field_deg, 0.0):
        return f"real chief ray at {lens.max_field_deg:g} deg does not reach the image"
    if not any(reaches(0.0, py) for py in (0.99, 0.75, 0.5, 0.25)):
        return "no real marginal ray (on axis, pupil fraction 0.25 to 0.99) reaches the image"
    return ""


def survey_file(path: Path, root: Path | None = None) -> FileResult:
    name = display_name(path.relative_to(root) if root else path)  # UTF-8, no control bytes
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise OSError(f"{size} bytes: larger than a lens file can be ({MAX_FILE_BYTES} bytes at most)")
        text, _ = _decode(path.read_bytes(), str(path))
    except (OSError, ZemaxError) as exc:
        return FileResult(name, False, "unreadable", False, False, None, None, None, printable(str(exc)))
    feats = _features(text)
    nominal = nominal_focal_length(text)
    res = FileResult(name, not feats, " ".join(feats), False, False, None, nominal, None, "")
    try:
        lens = Lens.from_file(path, strict=False)
    except (ValueError, EngineError) as exc:  # ZemaxError, PrescriptionError, GlassError, LensError
        res.error = _one_line(exc, path)
        return res
    res.imported = True
    try:
        res.error = _trace_check(lens)
        res.efl_mm = float(lens.paraxial()["efl_mm"])
    except (ValueError, EngineError) as exc:
        res.error = _one_line(exc, path)
        return res
    res.traced = not res.error
    if nominal and res.efl_mm is not None and math.isfinite(res.efl_mm):
        res.efl_ok = abs(res.efl_mm / nominal - 1) <= EFL_TOLERANCE
    return res


def _one_line(exc: Exception, path: Path) -> str:
    msg = str(exc).replace(str(path), display_name(path.name)).splitlines()
    return printable(f"{type(exc).__name__}: {msg[0] if msg else ''}")  # a file's bytes, escaped


def reason(error: str) -> str:
    """An error message with the file, line numbers, surface numbers and values taken out,
    so that files refused for the same reason count together."""
    msg = re.sub(r"^\w+: [^:]*\.zmx(:\d+)?: ", "", error)
    msg = re.sub(r"SURF \d+", "SURF n", msg)
    msg = re.sub(r"surfaces? \d+( and \d+)?", "surface n", msg)
    msg = re.sub(r"'[^']*'", "'…'", msg)
    msg = re.sub(r"(?<![\w-])-?\d+(\.\d+)?(e[-+]?\d+)?", "#", msg)
    return msg.split("; close matches")[0].split("; not substituted")[0][:160]


def survey(folder: Path) -> tuple[dict, list[FileResult]]:
    """Summary (counts, rates, top reasons) and per-file results for every .zmx under folder."""
    folder = Path(folder)
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() == ".zmx" and p.is_file())
    results = [survey_file(p, folder) for p in files]
    target = [r for r in results if r.target]
    with_nominal = [r for r in target if r.nominal_mm and r.traced and r.efl_ok is not None]
    good = [r for r in target if r.traced and r.efl_ok is not False]

    def rate(n, d):
        return round(n / d, 4) if d else None

    refused_target = Counter(reason(r.error) for r in target if not r.traced)
    refused_other = Counter(
        reason(r.error) if not r.imported else "imported anyway: " + r.features for r in results if not r.target
    )
    summary = {
        "folder": str(folder),
        "files": len(results),
        "imported": sum(r.imported for r in results),
        "traced": sum(r.traced for r in results),
        "target_files": len(target),
        "target_imported": sum(r.imported for r in target),
        "target_traced": sum(r.traced for r in target),
        "target_with_nominal_efl": len(with_nominal),
        "target_efl_within_1pct": sum(bool(r.efl_ok) for r in with_nominal),
        "target_rate": rate(len(good), len(target)),
        "efl_mismatches": [
            f"{r.file}: EFL {r.efl_mm:.4g} vs nominal {r.nominal_mm:g}" for r in with_nominal if not r.efl_ok
        ],
        "target_refused_reasons": refused_target.most_common(20),
        "other_refused_reasons": refused_other.most_common(20),
    }
    return summary, results


def results_csv(results: list[FileResult]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(FileResult.__dataclass_fields__))
    w.writeheader()
    for r in results:
        w.writerow(asdict(r))
    return buf.getvalue()
