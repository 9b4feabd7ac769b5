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

from ..errors import InputError


def _pairs(wavelengths_nm: Sequence[float], weights: Sequence[float] | None) -> list[tuple[float, float]]:
    ww = [1.0] * len(wavelengths_nm) if weights is None else list(weights)
    return [(float(w), float(x)) for w, x in zip(wavelengths_nm, ww)]


def best_focus_shift(
    lens_json: str,
    fields_deg: Sequence[float],
    wavelengths_nm: Sequence[float],
    weights: Sequence[float] | None = None,
    rings: int = 8,
    aiming: str = "paraxial",
) -> float:
    """Image-plane shift (mm; positive = away from the lens) minimizing the mean over
    ``fields_deg`` of the polychromatic centroid RMS spot squared (the engine's
    ``best_focus_batch``: polar pupil grid of ``rings`` rings; failed rays left out).
    Raises the engine's error if the lens cannot be traced."""
    from .. import engine

    r = engine.best_focus_batch(
        [lens_json], fields_deg=fields_deg, wavelengths=_pairs(wavelengths_nm, weights), rings=rings, aiming=aiming
    )
    if not r["ok"][0]:
        raise engine.EngineError(r["errors"][0])
    return float(r["shift_mm"][0])


def refocus_many(
    lenses: Sequence[dict],
    mode: str,
    fields_deg: Sequence[float],
    wavelengths_nm: Sequence[float],
    weights: Sequence[float] | None = None,
    primary_nm: float | None = None,
    rings: int = 8,
    aiming: str = "paraxial",
) -> list[str | None]:
    """Set each resolved lens dict's image distance by ``mode`` (in place): "best"
    (:func:`best_focus_shift`, one parallel engine call for all), "paraxial" (the paraxial
    focus at ``primary_nm``) or "fixed" (unchanged).  Returns, per lens, the engine's
    error message where it could not be refocused (that lens is left unchanged), else None."""
    from .. import engine

    if mode not in ("best", "paraxial", "fixed"):
        raise InputError(f"focus must be 'best', 'paraxial' or 'fixed', got {mode!r}")
    errors: list[str | None] = [None] * len(lenses)
    if mode == "paraxial":
        for k, lens in enumerate(lenses):
            try:
                bfl = engine.paraxial(json.dumps(lens), wavelength_nm=primary_nm)["bfl_mm"]
                lens["surfaces"][-1]["thickness"] = float(bfl)
            except engine.EngineError as exc:
                errors[k] = str(exc)
    elif mode == "best" and lenses:
        r = engine.best_focus_batch(
            [json.dumps(d) for d in lenses],
            fields_deg=fields_deg,
            wavelengths=_pairs(wavelengths_nm, weights),
            rings=rings,
            aiming=aiming,
        )
        for k, (lens, dz, err) in enumerate(zip(lenses, r["shift_mm"], r["errors"])):
            if err:
                errors[k] = err
            else:
                lens["surfaces"][-1]["thickness"] = float(lens["surfaces"][-1]["thickness"]) + float(dz)
    return errors


def refocus(
    lens: dict,
    mode: str,
    fields_deg: Sequence[float],
    wavelengths_nm: Sequence[float],
    weights: Sequence[float] | None = None,
    primary_nm: float | None = None,
) -> dict:
    """``lens`` (a resolved lens dict, changed in place and returned) with its image
    distance set by ``mode`` (see :func:`refocus_many`); raises the engine's error."""
    from .. import engine

    err = refocus_many([lens], mode, fields_deg, wavelengths_nm, weights, primary_nm)[0]
    if err:
        raise engine.EngineError(err)
    return lens
