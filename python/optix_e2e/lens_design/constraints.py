"""What makes a lens manufacturable: one definition, used by the design sampler (and so the
datasets the surrogates learn from), the design run's guard at every step and its final checks.

A design is checked as the engine traces it, at its own clear apertures: the clear
semi-diameters the traced prescription gives, else its own ray footprint (the rim rays and
the chief ray of each of its fields at its f-number, as Zemax sizes surfaces without a clear
semi-diameter). A design that opens its aperture, bends a surface or moves an element has
rims where its own rays pass, not where the base lens's did.

Checks (limits in mm from the space file's ``[constraints]`` table, :class:`Limits`):

* ``center_thickness`` / ``edge_thickness``: glass at the axis and at the rim >= limits,
* ``air_gap``: air between optical surfaces at the axis and at the rim >= limit, and a
  separate stop plane clear of its neighbours' rims,
* ``back_focal_distance``: last vertex to image >= limit,
* ``surfaces_cross``: consecutive surfaces never cross anywhere inside their apertures,
* ``aperture_outside_surface``: a clear semi-diameter beyond a conic's reach (or the
  sphere's radius),
* ``untraceable``: no ray of the footprint reaches some surface (the design cannot be sized),
  or at some field and wavelength (the lens's, the default RGB channels') the chief ray misses
  a surface or is totally reflected (the engine could not compute that field's PSF; a clear
  aperture clipping it is vignetting, and allowed),
* ``field_folds``: the image of the field folds (some pupil zone's image height stops growing
  with the field: rays of different fields cross; engine ``spot::field_fold``). Such a lens
  forms no image a per-field PSF can describe, and the engine refuses its relative
  illumination; the check costs about 7,000 traced rays.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .. import engine
from ..errors import InputError
from ..lens import Lens
from ..lens.prescription import SurfacesCrossError
from ..lens.surface import sag
from .optimizer import Constraints
from .space import Limits, SpaceError  # noqa: F401 - Limits: the space file's [constraints], read here

REASONS = (
    "center_thickness",
    "edge_thickness",
    "air_gap",
    "back_focal_distance",
    "surfaces_cross",
    "aperture_outside_surface",
    "untraceable",
    "field_folds",
)
_ROW_REASON = {
    "center_thickness": "center_thickness",
    "edge_thickness": "edge_thickness",
    "air_gap_center": "air_gap",
    "air_gap_edge": "air_gap",
    "stop_clearance": "air_gap",
    "back_focal_distance": "back_focal_distance",
}


def apertures(lens: Lens) -> np.ndarray:
    """Clear semi-diameters of ``lens``: the prescription's, else its own ray footprint
    (raises InputError when no ray reaches some surface)."""
    from .analysis import footprint

    given = [s.get("semi_diameter") for s in lens.surfaces]
    if all(g is not None for g in given):
        return np.array(given, float)
    fp = footprint(lens, lens.fields_deg)
    return np.array([g if g is not None else h for g, h in zip(given, fp)], float)


def geometry_problem(design: dict, semi_diameters: Sequence[float]) -> tuple[str, str] | None:
    """(reason, message) if the lens cannot exist: a clear semi-diameter beyond a surface's
    reach, or two consecutive surfaces crossing inside their apertures (checked at 17
    heights up to the smaller one).  The engine traces such lenses without complaint, so
    the sampler and the dataset generator check this themselves."""
    surfs = design["surfaces"]
    for i, (s, h) in enumerate(zip(surfs, semi_diameters)):
        if not np.isfinite(sag(s, h)):
            return (
                "aperture_outside_surface",
                f"surface {i + 1}: clear semi-diameter {h:.4g} mm lies beyond the surface (radius "
                f"{s.get('radius')}, conic {s.get('conic', 0.0)})",
            )
    z = np.concatenate([[0.0], np.cumsum([float(s["thickness"]) for s in surfs])])
    for i in range(len(surfs) - 1):
        r = np.linspace(0.0, min(semi_diameters[i], semi_diameters[i + 1]), 17)
        gap = (z[i + 1] + sag(surfs[i + 1], r)) - (z[i] + sag(surfs[i], r))
        if np.any(gap < 0.0):
            j = int(np.argmin(gap))
            return (
                "surfaces_cross",
                f"surfaces {i + 1} and {i + 2} cross inside the clear aperture "
                f"(gap {gap[j]:.4g} mm at r = {r[j]:.4g} mm)",
            )
    return None


def check_design(design: dict, semi_diameters: Sequence[float], limits: Limits) -> list[str]:
    """Reasons (from :data:`REASONS`) why the lens dict ``design`` is not manufacturable at
    the given clear semi-diameters; empty when it passes."""
    bad = geometry_problem(design, semi_diameters)
    if bad is not None and bad[0] == "aperture_outside_surface":
        return [bad[0]]
    reasons: list[str] = [bad[0]] if bad else []
    for row in _rows(design, semi_diameters, limits):
        reason = _ROW_REASON[row["name"].split("[")[0]]
        if not row["ok"] and reason not in reasons:
            reasons.append(reason)
    return reasons


def _rows(design: dict, semi_diameters: Sequence[float], limits: Limits) -> list[dict]:
    return Constraints(
        min_center=limits.min_center, min_edge=limits.min_edge, min_air_gap=limits.min_air_gap, min_bfd=limits.min_bfd
    ).evaluate(design, {}, semi_diameters)


def _as_lens(design: dict | Lens) -> Lens:
    return design if isinstance(design, Lens) else Lens(design, source="<design>")


def unreached_field(design: dict | Lens) -> str | None:
    """``"untraceable: ..."`` where at some field of the lens (a dict or a Lens), at one of its wavelengths
    or those of the default RGB channels (what the datasets compute), the chief ray misses
    the image (the engine then refuses that field's PSF), else None. Paraxial aiming, as the
    datasets trace."""
    from ..lens.model import DEFAULT_RGB_CHANNELS

    lens = _as_lens(design)
    wavelengths = sorted({float(w) for w in lens.wavelengths_nm} | {w for c in DEFAULT_RGB_CHANNELS for w, _ in c})
    fields = [float(f) for f in lens.fields_deg]
    try:  # every field and wavelength in one engine call (fields outer)
        status = lens._engine_call(engine.chief_ray_status, fields_deg=fields, wavelengths_nm=wavelengths)
    except Exception as err:  # noqa: BLE001 - the engine cannot read the lens
        return f"untraceable: {' '.join(str(err).split())}"
    for k, st in enumerate(status):
        if isinstance(st, str):  # the engine cannot launch the beam
            return f"untraceable: {lens.source}: {' '.join(st.split())}"
        # missed a surface, totally reflected or invalid (1, 3, 4); a clear aperture that
        # clips it (2) is vignetting, which the engine computes
        if st in (1, 3, 4):
            f, wl = fields[k // len(wavelengths)], wavelengths[k % len(wavelengths)]
            return f"untraceable: the chief ray at {f:g} deg, {wl:g} nm does not reach the image"
    return None


def field_folds(design: dict | Lens) -> str | None:
    """``"field_folds: ..."`` where the image of the lens's field (a dict or a Lens) folds (see
    the module's list), else None."""
    lens = _as_lens(design)
    try:
        f = lens.field_fold()
    except Exception as err:  # noqa: BLE001 - the engine cannot trace it: untraceable
        return f"untraceable: {' '.join(str(err).split())}"
    if f is None:
        return None
    return (
        f"field_folds: at pupil point ({f['px']:.2f}, {f['py']:.2f}) the image height falls by "
        f"{-f['step_mm']:.4g} mm near {f['field_deg']:.3g} deg"
    )


class ApertureError(InputError):
    """A design that cannot be sized; its message starts with the reason (:data:`REASONS`)."""


def own_apertures(design: dict) -> np.ndarray:
    """The clear semi-diameters a lens dict (as traced) is checked at: the ones it gives,
    else its own ray footprint. Raises ApertureError("surfaces_cross: ..." where surfaces
    cross inside the paraxial beam, "untraceable: ..." where no ray can size a surface)."""
    return _sized(design)[1]


def _sized(design: dict) -> tuple[Lens, np.ndarray]:
    """The lens of a dict and ``own_apertures``'s semi-diameters (one parse for every check)."""
    try:
        lens = Lens(design, source="<design>")
    except SurfacesCrossError as err:
        raise ApertureError(f"surfaces_cross: {' '.join(str(err).split())}") from None
    try:
        return lens, apertures(lens)
    except Exception as err:  # noqa: BLE001 - no ray reaches a surface, the engine refuses it
        raise ApertureError(f"untraceable: {' '.join(str(err).split())}") from None


class Manufacturability:
    """The limits applied to designs at their own clear apertures (the module's rule).

    ``problems(design)`` lists the reasons a lens dict (as traced) fails, empty when it is
    manufacturable; ``margins(design)`` gives each limit's value minus its bound (mm, >= 0
    where met, a fixed order for a given lens), what a guard needs to steer by.
    ``checks`` counts the designs looked at."""

    def __init__(self, limits: Limits, field_fold: bool = True):
        self.limits = limits
        self.field_fold = field_fold  # False: leave the fold check out (benches/ri_fold_check.py)
        self.checks = 0

    def problems(self, design: dict) -> list[str]:
        self.checks += 1
        try:
            lens, sd = _sized(design)
        except ApertureError as err:
            return [str(err)]
        reasons = check_design(design, sd, self.limits)
        if reasons:
            return reasons
        if (unreached := unreached_field(lens)) is not None:
            return [unreached]
        return [fold] if self.field_fold and (fold := field_folds(lens)) else []

    def margins(self, design: dict) -> np.ndarray:
        """Raises ApertureError where the design cannot be sized."""
        self.checks += 1
        sd = own_apertures(design)
        return np.array([r["value"] - r["limit"] for r in _rows(design, sd, self.limits) if "limit" in r])


def reason_of(problem: str) -> str:
    """The :data:`REASONS` entry of one of ``problems``' strings."""
    return problem.split(":")[0]
