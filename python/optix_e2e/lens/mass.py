"""How much glass a lens is: each element's volume and mass, and the lens's total.

An element is a run of non-air material between two surfaces (a cemented group counts each
glass apart). Its volume is the solid of revolution between the two sags out to the element's
outer radius, the larger of its surfaces' clear semi-diameters: where a surface's own clear
aperture ends before that radius it continues flat at its rim's sag (a ground flange), as a
moulded or edged singlet is made. No mount, no spacer: the optical glass only.

    V = integral_0^R 2 pi r (t + z_back(r) - z_front(r)) dr

with t the centre thickness and z the sags (lens/surface.py), by Gauss-Legendre quadrature on
each piece where both sags are smooth (exact to float64 for polynomial sags; a conic's square
root converges at 64 nodes to 1e-10 relative, checked in tests/lens/test_mass.py against a
sphere's cap in closed form).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from .surface import sag

#: Density at 20 C, g/cm^3: the catalog datasheets (Schott N-SF11 4.74, N-BK7 2.51,
#: N-SK16 3.58, N-SF5 2.86, F2 3.61; Ohara S-LAH64 4.33) and the optical plastics' usual
#: values (PMMA 1.19, polycarbonate 1.20, Zeonex E48R 1.01, polystyrene 1.05).
DENSITY_G_CM3 = {
    "PMMA": 1.19,
    "POLYCARB": 1.20,
    "PC": 1.20,
    "E48R": 1.01,
    "POLYSTYR": 1.05,
    "N-SF11": 4.74,
    "N-BK7": 2.51,
    "N-SK16": 3.58,
    "N-SF5": 2.86,
    "F2": 3.61,
    "S-LAH64": 4.33,
}

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(64)


def _material_name(m) -> str:
    return str(m.get("name", "") if isinstance(m, dict) else m)


def _is_air(m) -> bool:
    return _material_name(m).strip().lower() in ("air", "")


def _profile(s: dict, r: np.ndarray, own: float) -> np.ndarray:
    """The surface's sag out to its clear semi-diameter ``own``, flat beyond it."""
    return np.where(r <= own, sag(s, np.minimum(r, own), clip=True), sag(s, own, clip=True))


def element_volume_mm3(front: dict, back: dict, thickness: float) -> tuple[float, float]:
    """(volume mm^3, outer radius mm) of the glass between ``front`` and ``back`` (surface
    dicts with ``semi_diameter``), ``thickness`` apart on the axis."""
    sd = [front.get("semi_diameter"), back.get("semi_diameter")]
    if any(x is None or not float(x) > 0 for x in sd):
        raise InputError("an element's surfaces need clear semi-diameters for its volume (optix lens info writes them)")
    a, b = float(sd[0]), float(sd[1])
    outer = max(a, b)
    vol = 0.0
    for lo, hi in ((0.0, min(a, b)), (min(a, b), outer)):  # each piece smooth in both profiles
        if hi <= lo:
            continue
        r = 0.5 * (hi - lo) * _NODES + 0.5 * (hi + lo)
        h = thickness + _profile(back, r, b) - _profile(front, r, a)
        vol += 0.5 * (hi - lo) * float(np.sum(_WEIGHTS * 2.0 * math.pi * r * h))
    return vol, outer


def lens_mass(data: dict) -> dict:
    """Each glass element's surfaces, material, volume (mm^3), outer radius (mm) and mass (g)
    and the totals, for a prescription dict whose surfaces have clear semi-diameters (a
    Lens's ``raw`` as written by ``optix lens optimize --set-semi-diameters``); a material
    without a known density is an error naming it."""
    surfs = data["surfaces"]
    elements = []
    for i, s in enumerate(surfs[:-1]):
        if _is_air(s["material"]):
            continue
        name = _material_name(s["material"]).upper()
        if name not in DENSITY_G_CM3:
            raise InputError(
                f"surface {i + 1}: no density known for {name!r} (known: {', '.join(sorted(DENSITY_G_CM3))})"
            )
        vol, outer = element_volume_mm3(s, surfs[i + 1], float(s["thickness"]))
        if not vol > 0:
            raise InputError(f"surfaces {i + 1}-{i + 2}: the element's volume is not positive ({vol:.4g} mm^3)")
        mass = vol * 1e-3 * DENSITY_G_CM3[name]  # mm^3 -> cm^3
        elements.append(
            {
                "surfaces": [i + 1, i + 2],
                "material": name,
                "volume_mm3": vol,
                "outer_radius_mm": outer,
                "density_g_cm3": DENSITY_G_CM3[name],
                "mass_g": mass,
            }
        )
    return {
        "elements": elements,
        "n_elements": len(elements),
        "glass_volume_mm3": float(sum(e["volume_mm3"] for e in elements)),
        "mass_g": float(sum(e["mass_g"] for e in elements)),
    }
