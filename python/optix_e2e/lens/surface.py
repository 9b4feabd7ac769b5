"""Surface geometry of a prescription's surface dict (docs/lens-format.md): curvature and
sag, for drawing lenses and checking thicknesses on the Python side (the engine has its own
in crates/psf-engine/src/surface.rs)."""

from __future__ import annotations

import math

import numpy as np

#: How far below 0 the conic's 1 - (1+k) c^2 r^2 may round and still be the rim.
RIM_TOLERANCE = 1e-12


def curvature(s: dict) -> float:
    """1/radius in mm^-1; 0 for a plane ("inf", "infinity", null or a zero curvature)."""
    if s.get("curvature") is not None:
        return float(s["curvature"])
    r = s.get("radius")
    if r is None or (isinstance(r, str) and r.lower() in ("inf", "infinity")):
        return 0.0
    return 1.0 / float(r)


def sag(s: dict, r, *, clip: bool = False) -> np.ndarray:
    """Sag z(r) in mm: conic base c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2)) plus the
    aspheric terms a_k r^k (even k, and odd k up to 7 for an odd asphere).  Beyond the conic's reach (negative root) the result is NaN, or with
    ``clip`` the root is taken as 0 (the value at the conic's rim)."""
    c, k = curvature(s), float(s.get("conic", 0.0) or 0.0)
    if isinstance(r, (float, int, np.floating, np.integer)) and not isinstance(r, bool):
        return _sag_scalar(s, float(r), c, k, clip)
    r = np.asarray(r, dtype=float)
    rho = r * r
    arg = 1.0 - (1.0 + k) * c * c * rho
    if clip:
        arg = np.clip(arg, 0.0, None)
    # A rounding error below 0 is still the rim (the engine's RIM_TOLERANCE): a ball
    # lens's clear radius equal to its radius gives -2e-16 for R = 2.5, 5, 10.
    inside = arg >= -RIM_TOLERANCE
    z = c * rho / (1.0 + np.sqrt(np.clip(arg, 0.0, None)))
    for key, a in (s.get("aspheric") or {}).items():
        z = z + float(a) * np.abs(r) ** int(key[1:])  # "a4" -> r^4, "a1" -> |r|
    return np.where(inside, z, np.nan)


def _sag_scalar(s: dict, r: float, c: float, k: float, clip: bool) -> np.float64:
    """``sag`` at one height, without most of numpy's per-call overhead (the design checks
    call it tens of thousands of times); the same arithmetic, so the same bits (tested)."""
    rho = r * r
    arg = 1.0 - (1.0 + k) * c * c * rho
    if clip and arg < 0.0:
        arg = 0.0
    if not arg >= -RIM_TOLERANCE:
        return np.float64(np.nan)
    z = c * rho / (1.0 + math.sqrt(max(arg, 0.0)))
    for key, a in (s.get("aspheric") or {}).items():
        # numpy's power (not Python's, which differs in the last bit): the array path's bits
        z = z + float(a) * float(np.power(abs(r), int(key[1:])))
    return np.float64(z)
