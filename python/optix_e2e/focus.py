"""Refocusing a lens: the image-plane distance that minimizes the RMS spot over the field
(Zemax's "Quick Focus" on the RMS spot radius), or the paraxial focus.

Behind the last surface every ray is a straight line, so the spot at a shifted image plane
follows from one trace: x(d) = x + d ux/uz.  The weighted RMS spot squared about the
centroid is then a quadratic in d, summed over fields and minimized in closed form.
"""

from __future__ import annotations

import json
from typing import Sequence

import numpy as np

from .lens_optimizer import pupil_quadrature


def best_focus_shift(lens_json: str, fields_deg: Sequence[float], wavelengths_nm: Sequence[float],
                     weights: Sequence[float] | None = None, rings: int = 6, arms: int = 12,
                     aiming: str = "paraxial") -> float:
    """Image-plane shift (mm; positive = away from the lens) minimizing the mean over
    ``fields_deg`` of the polychromatic centroid RMS spot squared.  Rays that fail are
    left out; a field with no ray through contributes nothing."""
    from . import _engine

    px, py, pw = pupil_quadrature(rings, arms)
    ww = np.ones(len(wavelengths_nm)) if weights is None else np.asarray(weights, float)
    ww = ww / ww.sum()
    A = B = 0.0
    for f in fields_deg:
        xs, ss, ws = [], [], []
        for wl, wt in zip(wavelengths_nm, ww):
            tr = _engine.trace_field(lens_json, float(f), px, py, float(wl), aiming)
            ok = tr["status"] == 0
            if not ok.any():
                continue
            d = tr["direction"][ok]
            xs.append(tr["position"][ok, :2])
            ss.append(d[:, :2] / d[:, 2:3])          # dx/dz, dy/dz
            ws.append(wt * pw[ok])
        if not ws:
            continue
        x, s, w = np.concatenate(xs), np.concatenate(ss), np.concatenate(ws)
        w = w / w.sum()
        a = x - w @ x                                # deviation from the centroid
        b = s - w @ s                                # its rate of change with the shift
        A += float(np.sum(w[:, None] * a * b))
        B += float(np.sum(w[:, None] * b * b))
    return -A / B if B > 0 else 0.0


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
