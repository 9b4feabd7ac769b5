"""Scaling a lens to another focal length (OpticStudio's "Scale Lens" tool).

Every length scales by the factor s: radii (curvatures by 1/s), thicknesses, clear
semi-diameters, a finite object distance, the image's clear size and the entrance pupil
when the aperture is given as one.  Aspheric coefficients a_k of r^k scale by s^(1 - k), so
that the sag z(r) scales as a length.  Conics, glasses, field angles, the f-number and the
object-space NA are unchanged.  The scaled lens has the same ray angles, so every
aberration measured as a length (spot, OPD in mm) scales by s, while diffraction, set by
the f-number and the wavelength, does not: a scaled-down lens is nearer the diffraction
limit.
"""

from __future__ import annotations

import copy
import math

from ..errors import InputError

__all__ = ["scale_lens"]


def _len(v, s: float):
    """A length that may be ``"inf"`` / None (a plane, an unlimited aperture)."""
    if v is None or isinstance(v, str):
        return v
    return v * s


def scale_lens(data: dict, factor: float) -> dict:
    """A copy of the lens dict ``data`` with every length times ``factor`` (> 0)."""
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
        raise InputError(f"scale factor must be a positive number, got {factor!r}")
    out = copy.deepcopy(data)
    for srf in out["surfaces"]:
        if "radius" in srf:
            srf["radius"] = _len(srf["radius"], factor)
        if "curvature" in srf and srf["curvature"] is not None:
            srf["curvature"] = srf["curvature"] / factor
        srf["thickness"] = srf["thickness"] * factor
        if srf.get("semi_diameter") is not None:
            srf["semi_diameter"] = srf["semi_diameter"] * factor
        for key, a in (srf.get("aspheric") or {}).items():
            k = int(key[1:])
            srf["aspheric"][key] = a * factor ** (1 - k)
    if "object_distance" in out:
        out["object_distance"] = _len(out["object_distance"], factor)
    if out.get("image") and out["image"].get("semi_diameter") is not None:
        out["image"]["semi_diameter"] *= factor
    if out["aperture"]["type"] == "epd":
        out["aperture"]["value"] *= factor
    return out
