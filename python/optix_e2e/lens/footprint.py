"""Clear semi-diameters from the ray footprint, as Zemax's automatic semi-diameters: the
largest height at which the given rays cross each surface."""

from __future__ import annotations

from typing import Sequence

import numpy as np


def ray_footprint(
    lens_json: str,
    n_surfaces: int,
    fields_deg: Sequence[float],
    wavelengths_nm: Sequence[float],
    px,
    py,
    aiming: str = "paraxial",
) -> np.ndarray:
    """(n_surfaces,) largest radial height of the pupil rays (px, py) of every field and
    wavelength at each surface (0 where no ray gets there).

    Only rays that reach the image count: a ray that misses a surface or is totally
    reflected does not pass the lens at that field, and its path on the surfaces before
    (far out on an extended sphere, say) would size them for light that never arrives.
    """
    from .. import engine

    h = np.zeros(n_surfaces)
    for f in fields_deg:
        for wl in wavelengths_nm:
            d = engine.trace_field_path(lens_json, field_deg=f, px=px, py=py, wavelength_nm=wl, aiming=aiming)
            ok = d["status"] == 0
            if ok.any():
                p = d["path"][ok, :n_surfaces]
                h = np.maximum(h, np.hypot(p[..., 0], p[..., 1]).max(axis=0))
    return h
