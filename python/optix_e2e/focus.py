"""Refocusing a lens: the image-plane distance that minimizes the RMS spot over the field
(Zemax's "Quick Focus" on the RMS spot radius), or the paraxial focus.

Behind the last surface every ray is a straight line, so the spot at a shifted image plane
follows from one trace: x(d) = x + d ux/uz.  The weighted RMS spot squared about the
centroid is then a quadratic in d, summed over fields and minimized in closed form (in the
engine: crates/psf-engine/src/focus.rs).
"""

from __future__ import annotations

import json
from typing import Sequence


def best_focus_shift(lens_json: str, fields_deg: Sequence[float], wavelengths_nm: Sequence[float],
                     weights: Sequence[float] | None = None, rings: int = 8, aiming: str = "paraxial") -> float:
    """Image-plane shift (mm; positive = away from the lens) minimizing the mean over
    ``fields_deg`` of the polychromatic centroid RMS spot squared (the engine's
    ``best_focus_batch``: polar pupil grid of ``rings`` rings; failed rays left out).
    Raises the engine's error if the lens cannot be traced."""
    from . import _engine

    ww = [1.0] * len(wavelengths_nm) if weights is None else list(weights)
    r = _engine.best_focus_batch([lens_json], [float(f) for f in fields_deg],
                                 [(float(w), float(x)) for w, x in zip(wavelengths_nm, ww)], rings, aiming)
    if not r["ok"][0]:
        raise _engine.EngineError(r["errors"][0])
    return float(r["shift_mm"][0])


def refocus(lens: dict, mode: str, fields_deg: Sequence[float], wavelengths_nm: Sequence[float],
            weights: Sequence[float] | None = None, primary_nm: float | None = None) -> dict:
    """``lens`` (a resolved lens dict, changed in place and returned) with its image
    distance set by ``mode``: "best" (:func:`best_focus_shift`), "paraxial" (the paraxial
    focus at ``primary_nm``) or "fixed" (unchanged)."""
    from . import _engine

    if mode == "fixed":
        return lens
    last = lens["surfaces"][-1]
    if mode == "paraxial":
        last["thickness"] = float(_engine.paraxial(json.dumps(lens), primary_nm)["bfl_mm"])
    elif mode == "best":
        last["thickness"] = float(last["thickness"]) + best_focus_shift(
            json.dumps(lens), fields_deg, wavelengths_nm, weights)
    else:
        raise ValueError(f"focus must be 'best', 'paraxial' or 'fixed', got {mode!r}")
    return lens
