"""Classic nominal-design optimizer: least squares on an RMS spot merit with the paper's
manufacturing constraints (EFL, minimum center / edge thickness, minimum air gap, minimum
back focal distance).

Merit.  For each field f and wavelength l a fixed Gaussian-quadrature pupil grid (``rings``
radii, ``arms`` azimuths; exact for the polynomial aberrations of a rotationally symmetric
lens up to high order, as Zemax's default merit) is traced with the engine.  The residuals
are the transverse ray errors about the field's polychromatic centroid, each scaled by
sqrt(quadrature weight x wavelength weight x field weight), so that the sum of squares is
the weighted mean over fields of the centroid-referenced polychromatic mean-square spot
radius, and ``merit = sqrt(sum of squares)`` is an RMS spot radius (reported in um).  The
engine exposes no wavefront (OPD) output, so the merit is the spot merit only.

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

from .footprint import ray_footprint
from .lens import Lens
from .space import ParameterSpace
from .surface import sag as _surface_sag

__all__ = ["Constraints", "Merit", "OptimizeResult", "optimize", "sag", "element_geometry"]

FAILED_RAY_MM = 1.0     # residual given to each failed ray's x and y (mm)
REJECTED = 10.0         # residual value for every entry when the engine rejects a design
W_EFL = 100.0           # weight of the relative EFL error
W_GEOM = 100.0          # weight of a geometric violation (per mm)
MARGIN_MM = 1e-3        # the penalty aims this far inside each geometric limit, so that the
                        # small residual violation a penalty leaves still meets the limit


def _engine():
    from . import _engine as engine

    return engine


# ----- geometry --------------------------------------------------------------------------
def sag(s: dict, r) -> np.ndarray:
    """Surface sag z(r) in mm (optix_e2e.surface.sag; beyond the conic's reach, its rim value)."""
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
            clear.append({"surfaces": (a + 1, k + 1), "height_mm": float(semi_diameters[a]),
                          "edge_mm": z[k] - (z[a] + float(sag(surfs[a], semi_diameters[a])))})
        if after:
            b = after[0]
            clear.append({"surfaces": (k + 1, b + 1), "height_mm": float(semi_diameters[b]),
                          "edge_mm": (z[b] + float(sag(surfs[b], semi_diameters[b]))) - z[k]})
    return {"glass": glass, "air": air, "stop_clearance": clear}


# ----- constraints -----------------------------------------------------------------------
@dataclass
class Constraints:
    """The paper's constraints.  ``None`` = not enforced.  ``efl_tol`` is the relative EFL
    tolerance used to call the EFL target met in reports."""

    efl: float | None = None
    efl_tol: float = 1e-3
    min_center: float | None = None     # glass center thickness (mm)
    min_edge: float | None = None       # glass edge thickness at the clear semi-diameter (mm)
    min_air_gap: float | None = None    # air gap between optical surfaces, center and edge (mm)
    min_bfd: float | None = None        # last vertex to image plane (mm)

    def evaluate(self, lens: dict, paraxial: dict, semi_diameters) -> list[dict]:
        """One row per constraint instance: name, value, limit, violation (>= 0), ok."""
        rows = []
        if self.efl is not None:
            err = (paraxial["efl_mm"] - self.efl) / self.efl
            rows.append({"name": "efl", "value": paraxial["efl_mm"], "target": self.efl,
                         "residual": W_EFL * err, "violation": abs(err),
                         "ok": abs(err) <= self.efl_tol})
        geo = element_geometry(lens, semi_diameters)

        def ineq(name, value, limit):
            v = max(0.0, limit - value)
            rows.append({"name": name, "value": float(value), "limit": limit,
                         "residual": W_GEOM * max(0.0, limit + MARGIN_MM - value),
                         "violation": v, "ok": value >= limit - 1e-9})

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
        return rows


# ----- merit -----------------------------------------------------------------------------
def pupil_quadrature(rings: int, arms: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Legendre in rho^2 x uniform azimuths: points (px, py) and weights summing to 1
    such that sum w f(p) ~ mean of f over the unit pupil disk."""
    t, w = np.polynomial.legendre.leggauss(rings)
    t = 0.5 * (t + 1.0)            # rho^2 nodes in (0, 1)
    w = 0.5 * w
    theta = (np.arange(arms) + 0.5) * 2.0 * np.pi / arms
    rho = np.sqrt(t)[:, None]
    px = (rho * np.cos(theta)[None, :]).ravel()
    py = (rho * np.sin(theta)[None, :]).ravel()
    weights = np.repeat(w / arms, arms)
    return px, py, weights


class Merit:
    """Spot merit and constraint residuals of lens dicts (resolved materials) sharing the
    fields, wavelengths and sampling of ``base``."""

    def __init__(self, base: "Lens | dict", constraints: Constraints | None = None,
                 fields_deg: Sequence[float] | None = None,
                 field_weights: Sequence[float] | None = None,
                 rings: int = 6, arms: int = 12, aiming: str = "paraxial",
                 focus: str = "fixed"):
        base = Lens.load(base)
        self.fields = list(fields_deg) if fields_deg is not None else base.fields_deg
        fw = np.ones(len(self.fields)) if field_weights is None else np.asarray(field_weights, float)
        if len(fw) != len(self.fields) or np.any(fw < 0) or fw.sum() <= 0:
            raise ValueError(f"field weights {list(fw)} do not match the {len(self.fields)} fields "
                             f"or are not >= 0 with a positive sum")
        self.field_weights = fw / fw.sum()
        self.wavelengths = base.wavelengths_nm
        ww = np.asarray(base.wavelength_weights, float)
        self.wl_weights = ww / ww.sum()
        self.primary = base.primary_wavelength_nm
        self.px, self.py, self.pw = pupil_quadrature(rings, arms)
        self.aiming = aiming
        if focus not in ("fixed", "paraxial"):
            raise ValueError(f"focus must be 'fixed' or 'paraxial' (a BFL solve), got {focus!r}")
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
            par = _engine().paraxial(json.dumps(lens), None)
            lens["surfaces"][-1]["thickness"] = float(par["bfl_mm"])
        return lens

    def footprint(self, lens: dict, js: str) -> np.ndarray:
        """Clear semi-diameter of each surface: the largest rim-ray height over all fields
        and wavelengths (the engine's ray paths on the real surfaces)."""
        return ray_footprint(js, len(lens["surfaces"]), self.fields, self.wavelengths,
                             self.rim_px, self.rim_py, self.aiming)

    def evaluate(self, lens: dict, footprint: bool | None = None) -> dict:
        """Residual vector and a report of ``lens`` (already prepared).  The footprint
        (semi-diameters) is traced when edge constraints need it or ``footprint`` is True."""
        if footprint is None:
            c = self.constraints
            footprint = c.min_edge is not None or c.min_air_gap is not None
        E = _engine()
        js = json.dumps(lens)
        par = E.paraxial(js, None)
        res, per_field = [], []
        n_failed = 0
        for f, fw in zip(self.fields, self.field_weights):
            xs, ys, oks = [], [], []
            for wl in self.wavelengths:
                tr = E.trace_field(js, float(f), self.px, self.py, float(wl), self.aiming)
                ok = tr["status"] == 0
                xs.append(tr["position"][:, 0])
                ys.append(tr["position"][:, 1])
                oks.append(ok)
            x, y, ok = np.stack(xs), np.stack(ys), np.stack(oks)
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
            per_field.append({"field_deg": f, "rms_spot_um": 1e3 * math.sqrt(ms),
                              "failed_rays": int((~ok).sum())})
            s = np.sqrt(fw * wt)
            res.append((s * dx).ravel())
            res.append((s * dy).ravel())
        spot_res = np.concatenate(res)
        sd = self.footprint(lens, js) if footprint else np.zeros(len(lens["surfaces"]))
        rows = self.constraints.evaluate(lens, par, sd)
        con_res = np.array([r["residual"] for r in rows], float)
        merit_um = 1e3 * float(np.sqrt(np.sum(spot_res ** 2)))
        return {"residuals": np.concatenate([spot_res, con_res]), "merit_um": merit_um,
                "fields": per_field, "constraints": rows, "paraxial": par,
                "semi_diameters_mm": sd.tolist(), "failed_rays": n_failed}

    def residuals(self, lens: dict) -> np.ndarray:
        return self.evaluate(self.prepare(lens))["residuals"]


# ----- optimizer -------------------------------------------------------------------------
@dataclass
class OptimizeResult:
    lens: dict                      # optimized prescription (same material forms as input)
    values: dict                    # parameter name -> optimized value
    before: dict                    # Merit.evaluate report of the start (without residuals)
    after: dict                     # ... of the result
    nfev: int
    status: str
    history: list = field(default_factory=list)  # merit_um after each improvement

    def summary(self) -> dict:
        def strip(rep):
            return {k: v for k, v in rep.items() if k != "residuals"}

        return {"values": self.values, "before": strip(self.before), "after": strip(self.after),
                "nfev": self.nfev, "status": self.status,
                "constraints_satisfied": all(r["ok"] for r in self.after["constraints"])}


def optimize(lens: "Lens | dict", space: ParameterSpace, merit: Merit, max_nfev: int = 400,
             progress: Callable[[int, float, float, bool], None] | None = None,
             ftol: float = 1e-8, xtol: float = 1e-8, x_scale="jac") -> OptimizeResult:
    """Minimize ``merit`` over ``space`` starting from ``lens``.

    ``lens`` may carry catalog glass names (a raw dict): the optimizer evaluates the resolved
    copy and writes the variables (and a solved focus) back into the raw one.  Clear
    semi-diameters in ``lens`` are ignored while optimizing and kept as they are in the
    result (see :func:`set_semi_diameters` and ``OptimizeResult.after["semi_diameters_mm"]``).
    ``progress(nfev, merit_um, worst_violation, feasible)`` is called after each evaluation
    (Jacobian columns included); ``feasible``: every constraint met.
    """
    from scipy.optimize import least_squares

    raw = copy.deepcopy(lens.data if isinstance(lens, Lens) else lens)
    resolved = Lens.load(raw).data if not isinstance(lens, Lens) else copy.deepcopy(lens.data)
    # designs are evaluated without clear apertures (automatic semi-diameters, as Zemax
    # does while optimizing); the footprint gives the edge heights
    for s in resolved["surfaces"]:
        s["semi_diameter"] = None
    lo = np.array([p.min for p in space.params])
    hi = np.array([p.max for p in space.params])
    x0 = np.array(space.values(resolved))
    bad = space.check_bounds(resolved)
    if bad:
        raise ValueError("start point outside the parameter ranges: " + "; ".join(bad))
    span = hi - lo
    u0 = (x0 - lo) / span

    start = merit.prepare(resolved)
    before = merit.evaluate(start, footprint=True)
    nres = len(before["residuals"])
    count = {"n": 0}
    history = [before["merit_um"]]

    def fun(u):
        count["n"] += 1
        x = lo + np.clip(u, 0.0, 1.0) * span
        try:
            rep = merit.evaluate(merit.prepare(space.apply(resolved, x)), footprint=None)
            r = rep["residuals"]
            if r.shape != (nres,) or not np.all(np.isfinite(r)):
                raise ValueError("non-finite residuals")
        except Exception as exc:  # engine rejects the design: push the solver back
            if not _is_design_error(exc):
                raise
            if progress:
                progress(count["n"], math.nan, math.nan, False)
            return np.full(nres, REJECTED)
        if rep["merit_um"] < history[-1] and all(c["ok"] for c in rep["constraints"]):
            history.append(rep["merit_um"])
        if progress:
            worst = max((c["violation"] for c in rep["constraints"]), default=0.0)
            progress(count["n"], rep["merit_um"], worst, all(c["ok"] for c in rep["constraints"]))
        return r

    sol = least_squares(fun, u0, bounds=(0.0, 1.0), method="trf", x_scale=x_scale,
                        diff_step=1e-5, ftol=ftol, xtol=xtol, gtol=1e-12, max_nfev=max_nfev)
    x = lo + np.clip(sol.x, 0.0, 1.0) * span
    best = merit.prepare(space.apply(resolved, x))
    after = merit.evaluate(best, footprint=True)
    out = space.apply(raw, x)
    if merit.focus == "paraxial":
        out["surfaces"][-1]["thickness"] = best["surfaces"][-1]["thickness"]
    return OptimizeResult(lens=out, values=dict(zip(space.names, map(float, x))),
                          before=before, after=after, nfev=count["n"], status=sol.message,
                          history=history)


def _is_design_error(exc: Exception) -> bool:
    try:
        eng = _engine()
        if isinstance(exc, eng.EngineError):
            return True
    except ImportError:
        pass
    return isinstance(exc, (ValueError, ArithmeticError))


def set_semi_diameters(lens: dict, semi_diameters: Sequence[float], margin: float = 0.0,
                       decimals: int = 4) -> dict:
    """A copy of ``lens`` with each surface's clear semi-diameter set to the footprint
    (plus ``margin`` mm), rounded up to ``decimals``."""
    out = copy.deepcopy(lens)
    q = 10.0 ** decimals
    for s, h in zip(out["surfaces"], semi_diameters):
        s["semi_diameter"] = math.ceil((float(h) + margin) * q) / q
    return out


def report_dict(rep: dict) -> dict:
    """A JSON-friendly copy of an evaluate() report."""
    return {k: v for k, v in rep.items() if k != "residuals"}


def constraints_json(c: Constraints) -> dict:
    return asdict(c)
