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

    return engine.ray_footprint(
        lens_json,
        n_surfaces=n_surfaces,
        fields_deg=fields_deg,
        wavelengths_nm=wavelengths_nm,
        px=px,
        py=py,
        aiming=aiming,
    )
