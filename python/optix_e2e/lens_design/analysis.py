"""Lens analysis for figures and reports: surface geometry, ray footprint and ray fans for
the layout, spot diagrams.  The figures are drawn in :mod:`.plots`, the report written by
:mod:`.report`."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .. import engine
from ..errors import InputError
from ..lens import Lens
from ..lens.surface import curvature

__all__ = ["surface_geometry", "footprint", "ray_fans", "spot_diagram", "hexapolar"]


def _is_air(material, index: float) -> bool:
    return material == "air" or index == 1.0


def surface_geometry(lens: Lens, footprint: Sequence[float]) -> list[dict[str, Any]]:
    """Per surface: vertex z, drawn semi-diameter (the clear semi-diameter, else the ray
    footprint), whether glass follows it, and whether it is the stop."""
    z, out = 0.0, []
    n = lens.refractive_indices()
    for i, s in enumerate(lens.surfaces):
        sd = s.get("semi_diameter")
        h = float(sd) if sd else float(footprint[i])
        # Keep to where the conic is defined.
        c, k = curvature(s), float(s.get("conic", 0.0) or 0.0)
        if (1.0 + k) * c * c > 0:
            h = min(h, 0.999 / math.sqrt((1.0 + k) * c * c))
        out.append(
            {
                "index": i,
                "z": z,
                "semi_diameter": h,
                "clear_aperture": bool(sd),
                "glass_after": not _is_air(s["material"], float(n[i + 1])),
                "stop": bool(s.get("stop")),
                "surface": s,
            }
        )
        z += float(s["thickness"])
    return out


def _trace_paths(lens: Lens, field: float, px, py, wavelength_nm: float, aiming: str) -> dict:
    return engine.trace_field_path(
        lens.to_engine_json(), field_deg=field, px=px, py=py, wavelength_nm=wavelength_nm, aiming=aiming
    )


def footprint(lens: Lens, fields: Sequence[float], aiming: str = "paraxial", n_edge: int = 32) -> np.ndarray:
    """Largest height at each surface of the rays through the pupil rim (and the chief
    ray) of each of ``fields``, at the primary wavelength: the drawn size of surfaces
    without a clear semi-diameter (as Zemax's automatic semi-diameters)."""
    t = np.linspace(0.0, 2 * np.pi, n_edge, endpoint=False)
    px, py = np.append(np.sin(t), 0.0), np.append(np.cos(t), 0.0)
    h = engine.ray_footprint(
        lens.to_engine_json(),
        n_surfaces=len(lens.surfaces),
        fields_deg=sorted(set(fields)),
        wavelengths_nm=[lens.primary_wavelength_nm],
        px=px,
        py=py,
        aiming=aiming,
    )
    if np.any(h <= 0):
        bad = [i + 1 for i in np.flatnonzero(h <= 0)]
        raise InputError(f"no ray reaches surface(s) {bad}: cannot size them (give semi_diameter)")
    return h


def ray_fans(
    lens: Lens, fields: Sequence[float], n_rays: int = 9, aiming: str = "paraxial", wavelength_nm: float | None = None
) -> list[dict[str, Any]]:
    """Meridional (y-z) fans: ``n_rays`` rays from py = -1 to 1 per field.  Each ray is
    its list of (z, y) points, surface by surface to where it ends (the image, or the
    surface where it failed; ``ok`` says which); ``direction`` (the beam's) lets the
    caller extend it back.  Rays that miss surface 1 are left out."""
    if n_rays < 1:
        raise InputError(f"rays per field must be at least 1, got {n_rays}")
    wl = lens.primary_wavelength_nm if wavelength_nm is None else wavelength_nm
    py = np.linspace(-1.0, 1.0, n_rays) if n_rays > 1 else np.zeros(1)
    fans = []
    for f in fields:
        d = _trace_paths(lens, f, np.zeros_like(py), py, wl, aiming)
        keep = [j for j in range(py.size) if d["last"][j] >= 0]
        rays = [d["path"][j, : d["last"][j] + 1][:, [2, 1]] for j in keep]
        fans.append(
            {
                "field_deg": float(f),
                "rays": rays,
                "ok": [bool(d["status"][j] == 0) for j in keep],
                "direction": d["launch_direction"],
                "status": d["status"],
                "n_image": int(np.sum(d["status"] == 0)),
            }
        )
    return fans


def hexapolar(rings: int) -> tuple[np.ndarray, np.ndarray]:
    """Hexapolar pupil grid: the centre plus ``rings`` rings of 6k points (unit pupil)."""
    px, py = [0.0], [0.0]
    for k in range(1, rings + 1):
        t = np.arange(6 * k) * 2 * np.pi / (6 * k)
        px += list(k / rings * np.sin(t))
        py += list(k / rings * np.cos(t))
    return np.array(px), np.array(py)


def spot_diagram(lens: Lens, field: float, rings: int = 12, aiming: str = "paraxial") -> dict[str, Any]:
    """Image-plane points (um, relative to the weighted polychromatic centroid) per
    wavelength; RMS radius from the engine's dense polychromatic spot (64 rings)."""
    px, py = hexapolar(rings)
    pts, weights = [], []
    for wl, w in zip(lens.wavelengths_nm, lens.wavelength_weights):
        t = lens.trace_field(field, px, py, wl, aiming=aiming)
        ok = t["status"] == 0
        pts.append(t["position"][ok, :2] * 1e3)
        weights.append(np.full(int(ok.sum()), w))
    allp, allw = np.concatenate(pts), np.concatenate(weights)
    if allp.size == 0:
        raise InputError(f"no ray of field {field} deg reaches the image")
    centroid = (allw[:, None] * allp).sum(axis=0) / allw.sum()
    s = lens.spot(field, aiming=aiming)
    return {
        "field_deg": float(field),
        "centroid_um": centroid,
        "wavelengths_nm": lens.wavelengths_nm,
        "points_um": [p - centroid for p in pts],
        "rms_um": float(s["rms_um"]),
        "rms_um_per_wavelength": [float(v) for v in s["rms_um_per_wavelength"]],
        "relative_illumination": (None if s["relative_illumination"] is None else float(s["relative_illumination"])),
        "vignetting": s.get("vignetting"),
        "chief_y_mm": s.get("chief_y_mm"),
        "n_rays": int(px.size * len(pts)),
    }
