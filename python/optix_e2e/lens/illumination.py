"""Relative illumination checked by brute force: image irradiance counted from rays.

The engine computes relative illumination from the flux through the real pupil onto the
image point (``Lens.spot(...)["relative_illumination"]``; crates/psf-engine/src/spot.rs).
This module counts it the slow, assumption-free way, as a check: a uniform Lambertian
object at infinity sends rays of every direction (L, M) near the field through every point
of a square around the entrance pupil, each carrying the flux dA dL dM (its etendue); the
rays that land in a small box around the image point, over the box's area, are the
irradiance there. Sample points come from a scrambled Sobol sequence (seeded), so repeated
runs agree. ``tracer="optiland"`` traces the same rays with optiland (a test dependency),
an independent ray tracer.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .model import Lens


def _image_point(lens: Lens, field_deg: float, wavelength_nm: float) -> tuple[float, float]:
    chief = lens.trace_field(field_deg, [0.0], [0.0], wavelength_nm)
    if int(chief["status"][0]) != 0:
        raise InputError(f"the chief ray at {field_deg} deg does not reach the image")
    return float(chief["position"][0, 0]), float(chief["position"][0, 1])


def _optiland_tracer(lens: Lens, wavelength_nm: float):
    """Trace (origins, directions) with optiland: the lens rebuilt there with its indices at
    `wavelength_nm` as ideal materials and its clear semi-diameters as radial apertures."""
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic
    from optiland.physical_apertures import RadialAperture
    from optiland.rays import RealRays

    n = lens.refractive_indices(wavelength_nm)
    o = Optic()
    o.surfaces.add(index=0, radius=np.inf, thickness=np.inf)
    for i, s in enumerate(lens.surfaces, 1):
        r = s.get("radius", "inf")
        kw = dict(
            index=i,
            radius=np.inf if r == "inf" else float(r),
            thickness=float(s["thickness"]),
            material="air" if n[i] == 1.0 else IdealMaterial(float(n[i])),
            is_stop=bool(s.get("stop")),
            conic=float(s.get("conic", 0.0)),
        )
        if s.get("aspheric"):
            a = s["aspheric"]
            kw.update(surface_type="even_asphere", coefficients=[a.get(f"a{2 * k}", 0.0) for k in range(1, 11)])
        if s.get("semi_diameter") is not None:
            kw["aperture"] = RadialAperture(r_max=float(s["semi_diameter"]))
        o.surfaces.add(**kw)
    o.surfaces.add(index=len(lens.surfaces) + 1)
    o.set_aperture(aperture_type="EPD", value=lens.paraxial(wavelength_nm)["epd_mm"])
    o.fields.set_type(field_type="angle")
    o.fields.add(y=0.0)
    o.wavelengths.add(value=wavelength_nm / 1000.0, is_primary=True)

    def trace(origins: np.ndarray, dirs: np.ndarray):
        rays = RealRays(
            x=origins[:, 0],
            y=origins[:, 1],
            z=origins[:, 2],
            L=dirs[:, 0],
            M=dirs[:, 1],
            N=dirs[:, 2],
            intensity=np.ones(len(origins)),
            wavelength=np.full(len(origins), wavelength_nm / 1000.0),
        )
        o.surfaces.trace(rays)
        x, y, i = (np.asarray(v, dtype=float) for v in (rays.x, rays.y, rays.i))
        return x, y, np.isfinite(x) & np.isfinite(y) & (i > 0)

    return trace


def _engine_tracer(lens: Lens, wavelength_nm: float):
    from .. import engine

    text = lens.to_engine_json()

    def trace(origins: np.ndarray, dirs: np.ndarray):
        t = engine.trace(text, origins=origins, directions=dirs, wavelength_nm=wavelength_nm)
        ok = t["status"] == 0
        return t["position"][:, 0], t["position"][:, 1], ok

    return trace


def irradiance_count(
    lens: Lens,
    field_deg: float,
    wavelength_nm: float,
    *,
    n_rays: int = 2**21,
    box_um: float = 100.0,
    cone_mrad: float | None = None,
    tracer: str = "engine",
    aiming: str = "paraxial",
    seed: int = 0,
    chunk: int = 2**18,
) -> dict:
    """Image irradiance (flux per mm^2 for unit radiance) at the chief ray's image point,
    counted from `n_rays` rays, and the count of rays in the box (its relative statistical
    uncertainty is about 1/sqrt(count)). `box_um`: side of the counting box; `cone_mrad`:
    half-width of the direction square (default: enough for the box plus a 0.15 mm blur).
    `aiming`: the beam the engine's relative illumination uses: "paraxial" fills the paraxial
    entrance pupil (rays start only inside its circle in that plane, as if a stop sat there),
    "real" is limited by the lens's own clear apertures alone (give the stop its
    semi-diameter, as the engine's real aiming does)."""
    from scipy.stats import qmc

    par = lens.paraxial(wavelength_nm)
    px0, py0 = _image_point(lens, field_deg, wavelength_nm)
    t = np.radians(field_deg)
    l0, m0 = 0.0, np.sin(t)
    ze = float(par["entrance_pupil_z_mm"]) if "entrance_pupil_z_mm" in par else 0.0
    half_pupil = 0.75 * float(par["epd_mm"])
    efl = abs(float(par["efl_mm"]))
    b = box_um * 1e-3 / 2
    delta = cone_mrad * 1e-3 if cone_mrad is not None else (b + 0.15) / efl * np.cos(t) ** 2 * 1.5
    z_launch = min(ze, 0.0) - 20.0
    trace = _optiland_tracer(lens, wavelength_nm) if tracer == "optiland" else _engine_tracer(lens, wavelength_nm)
    sob = qmc.Sobol(d=4, scramble=True, seed=seed)
    area = np.pi * (0.5 * float(par["epd_mm"])) ** 2 if aiming == "paraxial" else (2 * half_pupil) ** 2
    weight = area * (2 * delta) ** 2 / n_rays
    flux, count, done = 0.0, 0, 0
    while done < n_rays:
        k = min(chunk, n_rays - done)
        u = sob.random(k)
        done += k
        if aiming == "paraxial":  # uniform over the paraxial entrance pupil's disc
            rho, phi = np.sqrt(u[:, 0]) * 0.5 * float(par["epd_mm"]), 2 * np.pi * u[:, 1]
            qx, qy = rho * np.cos(phi), rho * np.sin(phi)
        else:
            qx, qy = (2 * u[:, 0] - 1) * half_pupil, (2 * u[:, 1] - 1) * half_pupil
        dl, dm = l0 + (2 * u[:, 2] - 1) * delta, m0 + (2 * u[:, 3] - 1) * delta
        dn = np.sqrt(1 - dl**2 - dm**2)
        dirs = np.stack([dl, dm, dn], axis=1)
        s = (z_launch - ze) / dn
        origins = np.stack([qx + s * dl, qy + s * dm, np.full(k, z_launch)], axis=1)
        x, y, ok = trace(np.ascontiguousarray(origins), np.ascontiguousarray(dirs))
        hit = ok & (np.abs(x - px0) < b) & (np.abs(y - py0) < b)
        count += int(hit.sum())
        flux += weight * hit.sum()
    return {"irradiance": flux / (2 * b) ** 2, "count": count, "image_point_mm": [px0, py0]}


def relative_illumination_count(lens: Lens, field_deg: float, wavelength_nm: float, **kw) -> dict:
    """Brute-force relative illumination: `irradiance_count` at the field over the same on
    the axis, with its 1-sigma relative uncertainty from the two counts."""
    here = irradiance_count(lens, field_deg, wavelength_nm, **kw)
    axis = irradiance_count(lens, 0.0, wavelength_nm, **kw)
    ri = here["irradiance"] / axis["irradiance"]
    return {
        "relative_illumination": ri,
        "sigma": float(np.sqrt(1 / max(here["count"], 1) + 1 / max(axis["count"], 1))),
        "counts": [here["count"], axis["count"]],
    }


def relative_illumination_annulus(
    lens: Lens,
    heights_mm,
    wavelength_nm: float,
    *,
    theta_max_deg: float,
    n_rays: int = 2**21,
    half_width_mm: float = 0.15,
    axis_radius_mm: float = 0.5,
    seed: int = 0,
) -> dict:
    """Brute-force relative illumination of a uniform Lambertian object that fills every
    direction up to ``theta_max_deg``: rays with direction cosines uniform over that disc and
    start points uniform over the paraxial entrance pupil (Sobol, ``seed``), each carrying
    the same flux. By rotational symmetry the flux landing in the annulus |r - h| <
    ``half_width_mm`` over its area is the irradiance at image height h (on the axis, the disc
    r < ``axis_radius_mm``). Unlike `irradiance_count` (a small cone about one field) it counts
    light from every field, so it sees what a fold of the field's image sends to a point from
    far fields. Returns {"relative_illumination": [...], "counts": [...], "axis_count": n}."""
    from scipy.stats import qmc

    par = lens.paraxial(wavelength_nm)
    ze = float(par["entrance_pupil_z_mm"]) if "entrance_pupil_z_mm" in par else 0.0
    z_launch = min(ze, 0.0) - 20.0
    u = qmc.Sobol(d=4, scramble=True, seed=seed).random(n_rays)
    rho, phi = np.sqrt(u[:, 0]) * 0.5 * float(par["epd_mm"]), 2 * np.pi * u[:, 1]
    qx, qy = rho * np.cos(phi), rho * np.sin(phi)
    s_max = np.sin(np.radians(theta_max_deg))
    sr, sp = np.sqrt(u[:, 2]) * s_max, 2 * np.pi * u[:, 3]
    dl, dm = sr * np.cos(sp), sr * np.sin(sp)
    dn = np.sqrt(1 - dl**2 - dm**2)
    s = (z_launch - ze) / dn
    origins = np.stack([qx + s * dl, qy + s * dm, np.full(n_rays, z_launch)], axis=1)
    x, y, ok = _engine_tracer(lens, wavelength_nm)(origins, np.stack([dl, dm, dn], axis=1))
    r = np.hypot(x[ok], y[ok])
    axis_count = int(np.sum(r < axis_radius_mm))
    e0 = axis_count / (np.pi * axis_radius_mm**2)
    out, counts = [], []
    for h in np.atleast_1d(np.asarray(heights_mm, float)):
        lo, hi = max(0.0, h - half_width_mm), h + half_width_mm
        c = int(np.sum((r >= lo) & (r < hi)))
        counts.append(c)
        out.append(c / (np.pi * (hi**2 - lo**2)) / e0)
    return {"relative_illumination": out, "counts": counts, "axis_count": axis_count}
