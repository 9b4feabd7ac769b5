"""Classic nominal-design optimizer: least squares on an RMS spot merit with the paper's
manufacturing constraints (EFL, minimum center / edge thickness, minimum air gap, minimum
back focal distance).

Merit.  For each field f and wavelength l a fixed Gaussian-quadrature pupil grid (``rings``
radii, ``arms`` azimuths; exact for the polynomial aberrations of a rotationally symmetric
lens up to high order, as Zemax's default merit) is traced with the engine.  The residuals
are the transverse ray errors about the field's polychromatic centroid, each scaled by
sqrt(quadrature weight x wavelength weight x field weight), so that the sum of squares is
the weighted mean over fields of the centroid-referenced polychromatic mean-square spot
radius, and ``merit = sqrt(sum of squares)`` is an RMS spot radius (reported in um).

Wavefront merit (``kind="wavefront"``, OpticStudio's default "wavefront, centroid" merit):
the same pupil grid's optical path differences against the reference sphere about the
chief ray's image point, from the engine (``engine.wavefront``, per-ray arrays handed over
without a copy), piston removed per wavelength and tilt per wavelength (OpticStudio's
centroid reference, which leaves lateral colour to other operands) or per field
(``tilt="field"``: one image point for all wavelengths, lateral colour counts).  Residuals
are OPD in waves x sqrt(weights): ``merit`` is the weighted RMS wavefront error in waves.

Constraints enter as extra residuals (Zemax's "operands" with weights): the relative EFL
error, and each inequality's violation in mm (zero when met).  Edge thicknesses and edge
air gaps are taken at the clear semi-diameter, the largest ray height of the pupil rim over
all fields and wavelengths (Zemax's automatic semi-diameters), from the full sag (conic
and even-asphere terms).  Failing rays (missed, clipped, TIR) get a fixed large residual, not
NaN, and a prescription the engine rejects (e.g. crossing surfaces) gets a large constant
residual vector, so the solver backs off.

Solver.  ``scipy.optimize.least_squares`` with the trust-region reflective method ("trf"),
the bounded relative of damped least squares (Levenberg-Marquardt, what Zemax's DLS does):
each step solves the damped normal equations inside a trust region, the damping following
the ratio of actual to predicted merit decrease.  Variables are normalized to [0, 1] over
their parameter range; the Jacobian is by forward differences.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import asdict, dataclass, field
from typing import Callable, Sequence

import numpy as np

from .. import engine
from ..errors import InputError
from ..lens import Lens
from ..lens.pupil import pupil_quadrature
from ..lens.surface import sag as _surface_sag
from .space import ParameterSpace

__all__ = ["Constraints", "LensProblem", "Merit", "OptimizeResult", "optimize", "polish", "sag", "element_geometry"]

RAY_CLIPPED = 2  # the engine's status code of a ray stopped by a clear aperture (_engine.pyi)
FAILED_RAY_MM = 1.0  # residual given to each failed ray's x and y (mm)
FAILED_RAY_WAVES = 100.0  # ... and to its OPD in the wavefront merit (waves): above the OPD
# of any design worth keeping, so that losing a ray never pays
KINDS = ("spot", "wavefront")
UNITS = {"spot": "um", "wavefront": "waves"}
REJECTED = 10.0  # residual value for every entry when the engine rejects a design
W_EFL = 100.0  # weight of the relative EFL error
W_GEOM = 100.0  # weight of a geometric violation (per mm)
MARGIN_MM = 1e-3  # the penalty aims this far inside each geometric limit, so that the
# small residual violation a penalty leaves still meets the limit


# ----- geometry --------------------------------------------------------------------------
def sag(s: dict, r) -> np.ndarray:
    """Surface sag z(r) in mm (optix_e2e.lens.surface.sag; beyond the conic's reach, its rim value)."""
    return _surface_sag(s, r, clip=True)


def _is_air(material) -> bool:
    return isinstance(material, str) and material.lower() == "air"


def element_geometry(lens: dict, semi_diameters: Sequence[float]) -> dict:
    """Center and edge thicknesses of glass elements and air gaps between optical surfaces.

    Plane air-to-air surfaces (a separate stop, dummies) do not bound gaps: the air gap of
    lens 2 -> stop -> lens 3 is the distance between the lens surfaces.  Edges are taken
    at the larger semi-diameter of the two bounding surfaces (the element's rim).
    Returns lists of dicts {surfaces: (i, j) 1-based, center_mm, edge_mm, height_mm} under
    "glass" and "air", and under "stop_clearance" the axial room between a separate stop
    plane and the rims of its neighbours.
    """
    surfs = lens["surfaces"]
    z = np.concatenate([[0.0], np.cumsum([float(s["thickness"]) for s in surfs])])
    media = ["air"] + [s["material"] for s in surfs]
    # optical surfaces: the medium changes across them
    optical = [i for i in range(len(surfs)) if not (_is_air(media[i]) and _is_air(media[i + 1]))]
    glass, air = [], []
    for a, b in zip(optical, optical[1:]):
        h = float(max(semi_diameters[a], semi_diameters[b]))
        center = z[b] - z[a]
        edge = (z[b] + float(sag(surfs[b], h))) - (z[a] + float(sag(surfs[a], h)))
        row = {"surfaces": (a + 1, b + 1), "center_mm": center, "edge_mm": edge, "height_mm": h}
        (air if _is_air(media[a + 1]) else glass).append(row)
    # a stop plane between two optical surfaces must clear both rims (an iris sits there)
    stop = [i for i, s in enumerate(surfs) if s.get("stop")]
    clear = []
    if stop and stop[0] not in optical:
        k = stop[0]
        before = [i for i in optical if i < k]
        after = [i for i in optical if i > k]
        if before:
            a = before[-1]
            clear.append(
                {
                    "surfaces": (a + 1, k + 1),
                    "height_mm": float(semi_diameters[a]),
                    "edge_mm": z[k] - (z[a] + float(sag(surfs[a], semi_diameters[a]))),
                }
            )
        if after:
            b = after[0]
            clear.append(
                {
                    "surfaces": (k + 1, b + 1),
                    "height_mm": float(semi_diameters[b]),
                    "edge_mm": (z[b] + float(sag(surfs[b], semi_diameters[b]))) - z[k],
                }
            )
    return {"glass": glass, "air": air, "stop_clearance": clear}


# ----- constraints -----------------------------------------------------------------------
@dataclass
class Constraints:
    """The paper's constraints.  ``None`` = not enforced.  ``efl_tol`` is the relative EFL
    tolerance used to call the EFL target met in reports."""

    efl: float | None = None
    efl_tol: float = 1e-3
    min_center: float | None = None  # glass center thickness (mm)
    min_edge: float | None = None  # glass edge thickness at the clear semi-diameter (mm)
    min_air_gap: float | None = None  # air gap between optical surfaces, center and edge (mm)
    min_bfd: float | None = None  # last vertex to image plane (mm)
    min_image_height: float | None = None  # real chief-ray image height at the largest field (mm)

    def evaluate(self, lens: dict, paraxial: dict, semi_diameters, chief_height: float | None = None) -> list[dict]:
        """One row per constraint instance: name, value, limit, violation (>= 0), ok.
        ``chief_height``: the real chief ray's image height at the largest field (needed
        for ``min_image_height``: the image must reach the sensor's corner, whatever the
        distortion)."""
        rows = []
        if self.efl is not None:
            err = (paraxial["efl_mm"] - self.efl) / self.efl
            rows.append(
                {
                    "name": "efl",
                    "value": paraxial["efl_mm"],
                    "target": self.efl,
                    "residual": W_EFL * err,
                    "violation": abs(err),
                    "ok": abs(err) <= self.efl_tol,
                }
            )
        geo = element_geometry(lens, semi_diameters)

        def ineq(name, value, limit):
            v = max(0.0, limit - value)
            rows.append(
                {
                    "name": name,
                    "value": float(value),
                    "limit": limit,
                    "residual": W_GEOM * max(0.0, limit + MARGIN_MM - value),
                    "violation": v,
                    "ok": value >= limit - 1e-9,
                }
            )

        for g in geo["glass"]:
            tag = f"s{g['surfaces'][0]}-s{g['surfaces'][1]}"
            if self.min_center is not None:
                ineq(f"center_thickness[{tag}]", g["center_mm"], self.min_center)
            if self.min_edge is not None:
                ineq(f"edge_thickness[{tag}]", g["edge_mm"], self.min_edge)
        if self.min_air_gap is not None:
            for g in geo["air"]:
                tag = f"s{g['surfaces'][0]}-s{g['surfaces'][1]}"
                ineq(f"air_gap_center[{tag}]", g["center_mm"], self.min_air_gap)
                ineq(f"air_gap_edge[{tag}]", g["edge_mm"], self.min_air_gap)
            for g in geo["stop_clearance"]:
                tag = f"s{g['surfaces'][0]}-s{g['surfaces'][1]}"
                ineq(f"stop_clearance[{tag}]", g["edge_mm"], 0.0)
        if self.min_bfd is not None:
            ineq("back_focal_distance", float(lens["surfaces"][-1]["thickness"]), self.min_bfd)
        if self.min_image_height is not None:
            if chief_height is None:
                raise InputError("min_image_height needs the chief ray's image height")
            ineq("image_height", chief_height, self.min_image_height)
        return rows


# ----- merit -----------------------------------------------------------------------------
class Merit:
    """Spot merit and constraint residuals of lens dicts (resolved materials) sharing the
    fields, wavelengths and sampling of ``base``."""

    def __init__(
        self,
        base: "Lens | dict",
        constraints: Constraints | None = None,
        fields_deg: Sequence[float] | None = None,
        field_weights: Sequence[float] | None = None,
        rings: int = 6,
        arms: int = 12,
        aiming: str = "paraxial",
        focus: str = "fixed",
        kind: str = "spot",
        tilt: str = "wavelength",
    ):
        base = Lens.load(base)
        if kind not in KINDS:
            raise InputError(f"merit must be one of {', '.join(KINDS)}, got {kind!r}")
        if tilt not in ("wavelength", "field"):
            raise InputError(f"tilt must be 'wavelength' or 'field', got {tilt!r}")
        self.kind, self.tilt, self.unit = kind, tilt, UNITS[kind]
        self.fields = list(fields_deg) if fields_deg is not None else base.fields_deg
        fw = np.ones(len(self.fields)) if field_weights is None else np.asarray(field_weights, float)
        if len(fw) != len(self.fields) or np.any(fw < 0) or fw.sum() <= 0:
            raise InputError(
                f"field weights {list(fw)} do not match the {len(self.fields)} fields "
                f"or are not >= 0 with a positive sum"
            )
        self.field_weights = fw / fw.sum()
        self.wavelengths = base.wavelengths_nm
        ww = np.asarray(base.wavelength_weights, float)
        self.wl_weights = ww / ww.sum()
        self.primary = base.primary_wavelength_nm
        self.px, self.py, self.pw = pupil_quadrature(rings, arms)
        self.aiming = aiming
        if focus not in ("fixed", "paraxial"):
            raise InputError(f"focus must be 'fixed' or 'paraxial' (a BFL solve), got {focus!r}")
        self.focus = focus
        self.constraints = constraints or Constraints()
        # footprint rays: pupil rim, half azimuths (the lens is symmetric in x)
        th = np.linspace(0.0, np.pi, 9)
        self.rim_px, self.rim_py = np.cos(th), np.sin(th)
        self.rim_px = np.concatenate([self.rim_px, [0.0]])
        self.rim_py = np.concatenate([self.rim_py, [-1.0]])

    # -- preparing a design
    def prepare(self, lens: dict) -> dict:
        """Apply the focus solve (image at the paraxial focus of the primary wavelength)."""
        if self.focus == "paraxial":
            lens = copy.deepcopy(lens)
            par = engine.paraxial(json.dumps(lens))
            lens["surfaces"][-1]["thickness"] = float(par["bfl_mm"])
        return lens

    def footprint(self, lens: dict, js: str) -> np.ndarray:
        """Clear semi-diameter of each surface: the largest rim-ray height over all fields
        and wavelengths (the engine's ray paths on the real surfaces)."""
        return engine.ray_footprint(
            js,
            n_surfaces=len(lens["surfaces"]),
            fields_deg=self.fields,
            wavelengths_nm=self.wavelengths,
            px=self.rim_px,
            py=self.rim_py,
            aiming=self.aiming,
        )

    def _spot_terms(self, js: str) -> tuple[list, list, int]:
        """Spot residuals (mm x sqrt(weight)) and per-field RMS spot radii."""
        res, per_field, n_failed = [], [], 0
        for f, fw in zip(self.fields, self.field_weights):
            xs, ys, statuses = [], [], []
            for wl in self.wavelengths:
                tr = engine.trace_field(js, field_deg=f, px=self.px, py=self.py, wavelength_nm=wl, aiming=self.aiming)
                xs.append(tr["position"][:, 0])
                ys.append(tr["position"][:, 1])
                statuses.append(tr["status"])
            x, y, status = np.stack(xs), np.stack(ys), np.stack(statuses)
            ok = status == 0
            w = self.wl_weights[:, None] * self.pw[None, :] * ok
            wsum = w.sum()
            if wsum <= 0:
                cx = cy = 0.0
            else:
                cx, cy = (w * x).sum() / wsum, (w * y).sum() / wsum
            wt = self.wl_weights[:, None] * self.pw[None, :]
            dx = np.where(ok, x - cx, FAILED_RAY_MM)
            dy = np.where(ok, y - cy, FAILED_RAY_MM)
            n_failed += int((~ok).sum())
            # per-field RMS over transmitted rays (the reported figure)
            ms = ((w * ((x - cx) ** 2 + (y - cy) ** 2)).sum() / wsum) if wsum > 0 else math.inf
            per_field.append(
                {
                    "field_deg": f,
                    "rms_spot_um": 1e3 * math.sqrt(ms),
                    "failed_rays": int((~ok).sum()),
                    "clipped_rays": int((status == RAY_CLIPPED).sum()),
                }
            )
            s = np.sqrt(fw * wt)
            res.append((s * dx).ravel())
            res.append((s * dy).ravel())
        return res, per_field, n_failed

    def _wavefront_terms(self, js: str) -> tuple[list, list, int]:
        """OPD residuals (waves x sqrt(weight)) and per-field RMS wavefront errors."""
        res, per_field, n_failed = [], [], 0
        for f, fw in zip(self.fields, self.field_weights):
            wf = engine.wavefront(
                js,
                field_deg=f,
                px=self.px,
                py=self.py,
                weights=self.pw,
                wavelengths_nm=self.wavelengths,
                wavelength_weights=self.wl_weights,
                aiming=self.aiming,
                tilt=self.tilt,
            )
            ok = wf["status"] == 0
            opd = np.where(ok, wf["opd_waves"], FAILED_RAY_WAVES)
            n_failed += int((~ok).sum())
            wt = self.wl_weights[:, None] * self.pw[None, :]
            res.append((np.sqrt(fw * wt) * opd).ravel())
            rms = np.asarray(wf["rms_waves"])
            per_field.append(
                {
                    "field_deg": f,
                    "rms_wavefront_waves": float(np.sqrt(np.sum(self.wl_weights * rms**2))),
                    "rms_wavefront_waves_per_wavelength": rms.tolist(),
                    "failed_rays": int((~ok).sum()),
                }
            )
        return res, per_field, n_failed

    def evaluate(self, lens: dict, footprint: bool | None = None, full: bool = False) -> dict:
        """Residual vector and a report of ``lens`` (already prepared).  The footprint
        (semi-diameters) is traced when edge constraints need it or ``footprint`` is True.
        ``full``: the per-field rows carry both the RMS spot and the RMS wavefront error
        (else only the merit's own figure)."""
        if footprint is None:
            c = self.constraints
            footprint = c.min_edge is not None or c.min_air_gap is not None
        js = json.dumps(lens)
        par = engine.paraxial(js)
        terms = self._spot_terms if self.kind == "spot" else self._wavefront_terms
        res, per_field, n_failed = terms(js)
        if full:
            other = self._wavefront_terms if self.kind == "spot" else self._spot_terms
            try:
                extras = other(js)[1]
            except Exception as exc:  # e.g. no reference sphere (telecentric image space)
                if not _is_design_error(exc):
                    raise
                extras = [{"rms_wavefront_waves" if self.kind == "spot" else "rms_spot_um": None} for _ in per_field]
            for row, extra in zip(per_field, extras):
                row.update({k: v for k, v in extra.items() if k != "failed_rays"})
        merit_res = np.concatenate(res)
        sd = self.footprint(lens, js) if footprint else np.zeros(len(lens["surfaces"]))
        chief = None
        if self.constraints.min_image_height is not None:
            f = max(self.fields, key=abs)
            tr = engine.trace_field(
                js, field_deg=f, px=np.zeros(1), py=np.zeros(1), wavelength_nm=self.primary, aiming=self.aiming
            )
            # a failed chief ray: no image height (the constraint then counts fully violated)
            chief = abs(float(tr["position"][0, 1])) if tr["status"][0] == 0 else 0.0
        rows = self.constraints.evaluate(lens, par, sd, chief)
        con_res = np.array([r["residual"] for r in rows], float)
        value = float(np.sqrt(np.sum(merit_res**2)))
        if self.kind == "spot":
            value *= 1e3
        out = {
            "residuals": np.concatenate([merit_res, con_res]),
            "merit": value,
            "merit_kind": self.kind,
            "merit_unit": self.unit,
            "fields": per_field,
            "constraints": rows,
            "paraxial": par,
            "semi_diameters_mm": sd.tolist(),
            "failed_rays": n_failed,
        }
        if self.kind == "spot":
            out["merit_um"] = value
        return out

    def residuals(self, lens: dict) -> np.ndarray:
        return self.evaluate(self.prepare(lens))["residuals"]


# ----- optimizer -------------------------------------------------------------------------
@dataclass
class OptimizeResult:
    lens: dict  # optimized prescription (same material forms as input)
    values: dict  # parameter name -> optimized value
    before: dict  # Merit.evaluate report of the start (without residuals)
    after: dict  # ... of the result
    nfev: int
    status: str
    history: list = field(default_factory=list)  # merit after each feasible improvement

    def summary(self) -> dict:
        def strip(rep):
            return {k: v for k, v in rep.items() if k != "residuals"}

        return {
            "values": self.values,
            "before": strip(self.before),
            "after": strip(self.after),
            "nfev": self.nfev,
            "status": self.status,
            "constraints_satisfied": all(r["ok"] for r in self.after["constraints"]),
        }


class LensProblem:
    """``merit`` over ``space`` in unit coordinates: u in [0, 1]^n maps each variable
    linearly onto its range.  ``lens`` may carry catalog glass names (a raw dict): designs
    are evaluated on the resolved copy, results written back into the raw one.  Designs are
    evaluated without clear apertures (automatic semi-diameters, as Zemax does while
    optimizing); the ray footprint gives the edge heights."""

    def __init__(self, lens: "Lens | dict", space: ParameterSpace, merit: Merit):
        self.raw = copy.deepcopy(lens.data if isinstance(lens, Lens) else lens)
        self.resolved = Lens.load(self.raw).data if not isinstance(lens, Lens) else copy.deepcopy(lens.data)
        for s in self.resolved["surfaces"]:
            s["semi_diameter"] = None
        self.space, self.merit = space, merit
        self.lo = np.array([p.min for p in space.params], float)
        self.span = np.array([p.max for p in space.params], float) - self.lo
        bad = space.check_bounds(self.resolved)
        if bad:
            raise InputError("start point outside the parameter ranges: " + "; ".join(bad))
        self.u0 = (np.array(space.values(self.resolved)) - self.lo) / self.span
        self.n_res = len(self.report(self.u0)["residuals"])

    @property
    def n(self) -> int:
        return len(self.lo)

    def x(self, u) -> np.ndarray:
        return self.lo + np.clip(np.asarray(u, float), 0.0, 1.0) * self.span

    def design(self, u) -> dict:
        """The prepared (resolved, focus-solved) design at u."""
        return self.merit.prepare(self.space.apply(self.resolved, self.x(u)))

    def report(self, u, footprint: bool | None = True, full: bool = True) -> dict:
        return self.merit.evaluate(self.design(u), footprint=footprint, full=full)

    def evaluate(self, u) -> tuple[np.ndarray, dict | None]:
        """Residuals at u and the report; a design the engine rejects gets the constant
        REJECTED vector (no NaN reaches a solver) and no report."""
        try:
            rep = self.report(u, footprint=None, full=False)
            r = rep["residuals"]
            if r.shape != (self.n_res,) or not np.all(np.isfinite(r)):
                raise InputError("non-finite residuals")
            return r, rep
        except Exception as exc:
            if not _is_design_error(exc):
                raise
            return np.full(self.n_res, REJECTED), None

    def result(self, u, before: dict, nfev: int, status: str, history: list) -> "OptimizeResult":
        """The optimizer's result for the design at u (``before``: the start's report)."""
        return OptimizeResult(
            lens=self.lens_at(u),
            values=dict(zip(self.space.names, map(float, self.x(u)))),
            before=before,
            after=self.report(u),
            nfev=nfev,
            status=status,
            history=history,
        )

    def lens_at(self, u) -> dict:
        """The raw prescription (catalog names kept) with the variables (and a solved focus)."""
        out = self.space.apply(self.raw, self.x(u))
        if self.merit.focus == "paraxial":
            out["surfaces"][-1]["thickness"] = self.design(u)["surfaces"][-1]["thickness"]
        return out


class _OutOfTime(Exception):
    pass


def polish(
    problem,
    u0,
    max_nfev: int = 400,
    deadline: float | None = None,
    on_eval: Callable[[np.ndarray, np.ndarray, dict | None], None] | None = None,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    x_scale="jac",
) -> tuple[np.ndarray, int, str]:
    """Damped least squares (trust-region reflective) from ``u0`` on ``problem``
    (``evaluate(u) -> (residuals, report)``, ``n``).  Stops at ``deadline``
    (time.monotonic()) with the best point evaluated so far.  Returns (u, nfev, status)."""
    import time

    from scipy.optimize import least_squares

    best = {"cost": math.inf, "u": np.clip(np.asarray(u0, float), 0.0, 1.0), "n": 0}

    def fun(u):
        if deadline is not None and time.monotonic() > deadline:
            raise _OutOfTime
        best["n"] += 1
        r, rep = problem.evaluate(u)
        cost = float(r @ r)
        if cost < best["cost"]:
            best["cost"], best["u"] = cost, np.clip(np.array(u, float), 0.0, 1.0)
        if on_eval:
            on_eval(u, r, rep)
        return r

    try:
        sol = least_squares(
            fun,
            best["u"],
            bounds=(0.0, 1.0),
            method="trf",
            x_scale=x_scale,
            diff_step=1e-5,
            ftol=ftol,
            xtol=xtol,
            gtol=1e-12,
            max_nfev=max_nfev,
        )
    except _OutOfTime:
        return best["u"], best["n"], "stopped at the time budget"
    return np.clip(sol.x, 0.0, 1.0), best["n"], sol.message


def optimize(
    lens: "Lens | dict",
    space: ParameterSpace,
    merit: Merit,
    max_nfev: int = 400,
    progress: Callable[[int, float, float, bool], None] | None = None,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    x_scale="jac",
) -> OptimizeResult:
    """Minimize ``merit`` over ``space`` starting from ``lens`` (local: the minimum of the
    start's basin; see :mod:`optix_e2e.lens_design.global_search` for the global search).

    Clear semi-diameters in ``lens`` are ignored while optimizing and kept as they are in
    the result (see :func:`set_semi_diameters` and ``OptimizeResult.after["semi_diameters_mm"]``).
    ``progress(nfev, merit, worst_violation, feasible)`` is called after each evaluation
    (Jacobian columns included); ``feasible``: every constraint met.
    """
    problem = LensProblem(lens, space, merit)
    before = problem.report(problem.u0)
    history = [before["merit"]]
    count = {"n": 0}

    def on_eval(u, r, rep):
        count["n"] += 1
        if rep is None:
            if progress:
                progress(count["n"], math.nan, math.nan, False)
            return
        feasible = all(c["ok"] for c in rep["constraints"])
        if rep["merit"] < history[-1] and feasible:
            history.append(rep["merit"])
        if progress:
            worst = max((c["violation"] for c in rep["constraints"]), default=0.0)
            progress(count["n"], rep["merit"], worst, feasible)

    u, nfev, status = polish(problem, problem.u0, max_nfev, on_eval=on_eval, ftol=ftol, xtol=xtol, x_scale=x_scale)
    return problem.result(u, before, nfev, status, history)


def _is_design_error(exc: Exception) -> bool:
    return isinstance(exc, (engine.EngineError, ValueError, ArithmeticError))


def set_semi_diameters(lens: dict, semi_diameters: Sequence[float], margin: float = 0.0, decimals: int = 4) -> dict:
    """A copy of ``lens`` with each surface's clear semi-diameter set to the footprint
    (plus ``margin`` mm), rounded up to ``decimals``."""
    out = copy.deepcopy(lens)
    q = 10.0**decimals
    for s, h in zip(out["surfaces"], semi_diameters):
        s["semi_diameter"] = math.ceil((float(h) + margin) * q) / q
    return out


def report_dict(rep: dict) -> dict:
    """A JSON-friendly copy of an evaluate() report."""
    return {k: v for k, v in rep.items() if k != "residuals"}


def constraints_json(c: Constraints) -> dict:
    return asdict(c)
