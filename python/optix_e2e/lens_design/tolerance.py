"""Tolerance analysis over a parameter space: sensitivities, ranges from a budget, MC yield.

Metric.  The polychromatic, centroid-referenced RMS spot radius of each field
(:class:`optix_e2e.lens_design.optimizer.Merit`, Gaussian pupil quadrature); the figure that is
budgeted is the worst field's.  By default designs are traced with free apertures (clear
semi-diameters removed, as the optimizer does), so a perturbation changes the image and not
which rays a rim stops.  ``apertures="fixed"`` keeps the nominal's clear semi-diameters
(the stop's is dropped: the iris follows the f-number), as ``optix dataset --apertures
fixed`` does: a lens whose edge field is vignetted by design is then judged on the rays
that pass, as Zemax's RMS spot of a vignetted field is (clipped rays are left out, lost
rays still fail the design).  The manufacturability checks of the Monte Carlo draws use the
nominal's clear semi-diameters (:func:`optix_e2e.lens_design.sampling.apertures`).

Sensitivity.  Each parameter alone is moved to nominal + k * step for k = -2, -1, +1, +2
(the others at nominal) and the RMS spot of every field is traced.  Per field f a quadratic
``R_f(d) = R_f(0) + a_f d + b_f d^2`` is fitted (least squares over the four offsets,
through the traced nominal): at an optimized nominal a_f ~ 0 and the change is quadratic,
which a one-sided linear sensitivity would miss.  The worst-field model is
``W(d) = max_f R_f(d)``.  Default steps (:func:`default_step`, all scaled by
``step_scale``):

* radius: 0.1 % of |R|
* thickness / air_gap: 0.01 mm
* conic: 0.01
* asphere a_n: the coefficient giving 0.5 um of sag at the surface's clear semi-diameter h
  (a_n h^n = 5e-4 mm)
* f_number / epd: 1 % of the value

Budget to ranges.  The allowed growth B of the worst-field RMS is shared by root-sum-square
over the P parameters, equal shares s = B / sqrt(P) (so sqrt(sum s^2) = B, the usual
statistical tolerance allocation), and each parameter's tolerance t is the smallest
half-width whose model growth ``G(t) = max_{|d| <= t} W(d) - W(0)`` reaches s (exact: each
quadratic's maximum over an interval is at an end or at its vertex; bisection on t).  A
parameter whose growth stays below its share up to the cap gets the cap: the farther end of
the given space's range from the nominal.  The proposed range is nominal +- t, cut to the
given range (when the nominal lies inside it) and to physical validity (radius keeps its
sign, thickness / f-number / EPD > 0, air gap >= 0).  The model growth at each proposed range
is checked by tracing its two ends.

Monte Carlo.  ``n`` designs are drawn uniformly (seeded PCG64, :func:`sample_designs`) from
a space, every parameter varying within its range at once, candidates failing the space's
manufacturability limits being redrawn (counted by reason); each accepted design's
worst-field RMS is traced.  Yield = fraction with worst-field RMS <= spec, with its binomial
standard error sqrt(y (1 - y) / n).  A design the engine rejects, or one losing rays
(missed surface, total internal reflection), counts as out of spec, with its reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..lens import Lens
from .optimizer import Merit, _is_design_error
from .space import APERTURE_KINDS, ASPHERE_KINDS, Parameter, ParameterSpace, SpaceError

__all__ = [
    "DEFAULT_STEPS",
    "OFFSETS",
    "APERTURE_MODES",
    "DEFAULT_PUPIL",
    "default_step",
    "free_apertures",
    "traced_apertures",
    "evaluate_fields",
    "ParamSensitivity",
    "Sensitivity",
    "sensitivity",
    "Allocation",
    "allocate",
    "proposed_space",
    "MonteCarlo",
    "monte_carlo",
    "check_space_fits",
    "model_worst",
    "rss",
]

OFFSETS = (-2.0, -1.0, 1.0, 2.0)  # multiples of the step traced per parameter
ASPHERE_SAG_MM = 5e-4  # asphere step: a_n h^n = 0.5 um at the clear semi-diameter
DEFAULT_STEPS = {
    "radius": "0.1 % of |R|",
    "thickness": "0.01 mm",
    "air_gap": "0.01 mm",
    "conic": "0.01",
    "asphere_*": "a_n with a_n h^n = 0.5 um at the clear semi-diameter h",
    "f_number": "1 % of the value",
    "epd": "1 % of the value",
}


def default_step(p: Parameter, value: float, semi_diameter: float | None = None) -> float:
    """The default perturbation step of parameter ``p`` at ``value`` (see the module doc)."""
    if p.kind == "radius":
        if not math.isfinite(value) or value == 0:
            raise SpaceError(
                f"parameter {p.name!r}: radius {value} has no relative step "
                f"(a flat surface: use a curvature-free parameter)"
            )
        return 1e-3 * abs(value)
    if p.kind in ("thickness", "air_gap"):
        return 0.01
    if p.kind == "conic":
        return 0.01
    if p.kind in APERTURE_KINDS:
        return 0.01 * abs(value)
    if p.kind in ASPHERE_KINDS:
        h = semi_diameter if semi_diameter and semi_diameter > 0 else 10.0
        return ASPHERE_SAG_MM / h ** ASPHERE_KINDS[p.kind]
    raise SpaceError(f"parameter {p.name!r}: no default step for kind {p.kind!r}")


APERTURE_MODES = ("free", "fixed")
# pupil quadrature (rings, arms) per aperture mode.  Gaussian quadrature is exact for the
# smooth aberration polynomials of a full pupil; a pupil cut by clear apertures is not smooth,
# and its RMS converges slowly: apo-gauss-8e-mv's vignetted 23.94 deg field gives 2.16 / 3.36
# / 3.52 um at 6 x 12 / 16 x 32 / 32 x 64 against the engine's 128-ring 3.44 um
DEFAULT_PUPIL = {"free": (6, 12), "fixed": (32, 64)}


def free_apertures(lens: dict) -> dict:
    """A copy of a lens dict with every clear semi-diameter removed (no clipping)."""
    return traced_apertures(lens, "free")


def check_apertures(apertures: str) -> None:
    if apertures not in APERTURE_MODES:
        raise SpaceError(f"apertures must be one of {', '.join(APERTURE_MODES)}, got {apertures!r}")


def traced_apertures(lens: dict, apertures: str = "free") -> dict:
    """The lens dict as the analysis traces it: ``free`` (no clear apertures) or ``fixed``
    (the prescription's clear semi-diameters, the stop's dropped: the iris follows the
    f-number): the dataset's ``--apertures auto`` and ``fixed``, by its own definition."""
    from ..lens.apertures import engine_base

    check_apertures(apertures)
    return engine_base(lens, "auto" if apertures == "free" else "fixed")


def evaluate_fields(merit: Merit, design: dict, apertures: str = "free") -> np.ndarray:
    """Per-field RMS spot (um) of a resolved lens dict, traced with ``apertures``
    (:func:`traced_apertures`).  Raises ``ValueError`` when rays are lost (missed surface or
    total internal reflection: the RMS would be over the survivors only); with fixed
    apertures, rays a clear aperture stops are vignetting, not a failure, but a field that
    they stop entirely is."""
    rep = merit.evaluate(traced_apertures(design, apertures), footprint=False)
    clipped = sum(f.get("clipped_rays", 0) for f in rep["fields"]) if apertures == "fixed" else 0
    if rep["failed_rays"] - clipped:
        raise InputError(f"{rep['failed_rays'] - clipped} rays lost (missed surface or total internal reflection)")
    r = np.array([f["rms_spot_um"] for f in rep["fields"]], float)
    if not np.all(np.isfinite(r)):
        raise InputError("no rays reach the image")
    return r


def _reason(exc: Exception) -> str:
    """A short, countable reason for a failed design."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if "rays lost" in text:
        return "rays lost"
    return f"{type(exc).__name__}: {text[:100]}"


def _fit(d: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(a, b) of y = a d + b d^2 (least squares; NaN rows ignored)."""
    ok = np.isfinite(y)
    if ok.sum() < 2:
        return math.nan, math.nan
    A = np.stack([d[ok], d[ok] ** 2], axis=1)
    (a, b), *_ = np.linalg.lstsq(A, y[ok], rcond=None)
    return float(a), float(b)


# ----- sensitivity -----------------------------------------------------------------------
@dataclass
class ParamSensitivity:
    param: Parameter
    nominal: float
    step: float
    deltas: np.ndarray  # (4,) parameter offsets traced (units of the parameter)
    fields: np.ndarray  # (4, F) per-field RMS (um); NaN where the design failed
    nominal_fields: np.ndarray  # (F,)
    a: np.ndarray  # (F,) linear coefficients of each field's model (um / unit)
    b: np.ndarray  # (F,) quadratic coefficients (um / unit^2)
    failed: list  # reasons of failed offsets

    @property
    def worst(self) -> np.ndarray:
        return self.fields.max(axis=1)

    @property
    def mean(self) -> np.ndarray:
        return self.fields.mean(axis=1)

    def _step_change(self, y: np.ndarray, y0: float) -> float:
        sel = np.abs(np.abs(self.deltas) - self.step) <= 1e-9 * self.step
        v = np.abs(y[sel] - y0)
        return float(np.nanmax(v)) if np.any(np.isfinite(v)) else math.nan

    @property
    def d_worst_step(self) -> float:
        """Largest |change| of the worst-field RMS at +-1 step (um): the ranking figure."""
        return self._step_change(self.worst, float(self.nominal_fields.max()))

    @property
    def d_mean_step(self) -> float:
        return self._step_change(self.mean, float(self.nominal_fields.mean()))

    def worst_fit(self) -> tuple[float, float]:
        """(linear, quadratic) coefficients fitted to the worst-field RMS curve itself."""
        return _fit(self.deltas, self.worst - self.nominal_fields.max())

    def mean_fit(self) -> tuple[float, float]:
        return _fit(self.deltas, self.mean - self.nominal_fields.mean())

    def predict(self, d) -> np.ndarray:
        """Model per-field RMS at offset(s) ``d``: shape (..., F)."""
        d = np.asarray(d, float)[..., None]
        return self.nominal_fields + self.a * d + self.b * d**2

    def predict_worst(self, d) -> np.ndarray:
        return self.predict(d).max(axis=-1)

    def growth(self, t: float, side: str = "both") -> float:
        """Model growth of the worst-field RMS, max over offsets in [-t, t] ("both"),
        [0, t] ("plus") or [-t, 0] ("minus"); t >= 0."""
        lo, hi = {"both": (-t, t), "plus": (0.0, t), "minus": (-t, 0.0)}[side]
        cand = [lo, hi, 0.0]
        with np.errstate(divide="ignore", invalid="ignore"):
            v = -self.a / (2.0 * self.b)
        cand += [x for x, bb in zip(v, self.b) if bb < 0 and np.isfinite(x) and lo < x < hi]
        return float(self.predict_worst(np.array(cand)).max() - self.nominal_fields.max())

    def growth_range(self, lo: float, hi: float) -> float:
        """Model growth, max over the parameter values [lo, hi] (absolute values)."""
        a, b = lo - self.nominal, hi - self.nominal
        cand = [a, b] + ([0.0] if a <= 0 <= b else [])
        with np.errstate(divide="ignore", invalid="ignore"):
            v = -self.a / (2.0 * self.b)
        cand += [x for x, bb in zip(v, self.b) if bb < 0 and np.isfinite(x) and a < x < b]
        return float(self.predict_worst(np.array(cand)).max() - self.nominal_fields.max())

    @property
    def fit_rms_um(self) -> float:
        """RMS residual of the per-field quadratic fits over the traced offsets (um)."""
        r = self.predict(self.deltas) - self.fields
        return float(np.sqrt(np.nanmean(r**2))) if np.any(np.isfinite(r)) else math.nan


@dataclass
class Sensitivity:
    space: ParameterSpace
    fields_deg: list
    nominal_fields: np.ndarray
    rows: list  # ParamSensitivity, in the space's order
    step_scale: float

    @property
    def nominal_worst(self) -> float:
        return float(self.nominal_fields.max())

    @property
    def nominal_mean(self) -> float:
        return float(self.nominal_fields.mean())

    def ranking(self) -> list:
        """Rows from the most to the least sensitive (|worst-field change| at +-1 step;
        ties and failures broken by the model growth at one step)."""

        def key(r):
            d = r.d_worst_step
            return (-(d if math.isfinite(d) else math.inf), -r.growth(r.step))

        return sorted(self.rows, key=key)

    def row(self, name: str) -> ParamSensitivity:
        for r in self.rows:
            if r.param.name == name:
                return r
        raise KeyError(name)


def check_space_fits(space: ParameterSpace, lens: dict) -> list[str]:
    """Raise :class:`SpaceError` when a parameter does not fit ``lens`` (surface beyond the
    lens, thickness kind on an air gap or the reverse, aperture kind not the lens's); return
    warnings for nominal values outside the space's ranges."""
    n = len(lens["surfaces"])
    for p in space.params:
        if p.kind not in APERTURE_KINDS:
            if not 1 <= p.surface <= n:
                raise SpaceError(
                    f"{space.source}: parameter {p.name} names surface {p.surface}; the lens has surfaces 1..{n}"
                )
            if p.kind in ("thickness", "air_gap"):
                mat = lens["surfaces"][p.surface - 1].get("material")
                air = mat == "air" or (isinstance(mat, str) and mat.lower() == "air")
                if air != (p.kind == "air_gap"):
                    raise SpaceError(
                        f"{space.source}: parameter {p.name} is a {p.kind} but surface "
                        f"{p.surface} of the lens is followed by "
                        f"{'air' if air else 'glass'}"
                    )
        p.get(lens)  # aperture kinds must match the lens's aperture type
    return space.check_bounds(lens)


def sensitivity(
    space: ParameterSpace,
    lens: "Lens | dict",
    merit: Merit,
    step_scale: float = 1.0,
    steps: dict | None = None,
    semi_diameters: Sequence[float] | None = None,
    progress: Callable[[int, int], None] | None = None,
    apertures: str = "free",
) -> Sensitivity:
    """Trace each parameter at nominal + k step, k in :data:`OFFSETS`, and fit the models.

    ``lens``: the nominal (a Lens or a resolved lens dict); ``steps``: name -> step overriding
    :func:`default_step`; ``semi_diameters``: per-surface heights for the asphere steps
    (default: the lens's clear semi-diameters, else its ray footprint); ``apertures``: free
    or fixed (:func:`traced_apertures`)."""
    if not step_scale > 0:
        raise InputError(f"step scale must be > 0, got {step_scale}")
    check_apertures(apertures)
    lens = Lens.load(lens)
    base = lens.data
    check_space_fits(space, base)
    if semi_diameters is None:
        from .constraints import apertures as clear_semi_diameters

        semi_diameters = clear_semi_diameters(lens)
    nominal_fields = evaluate_fields(merit, base, apertures)
    x0 = np.array(space.values(base), float)
    total = len(space) * len(OFFSETS)
    rows, done = [], 0
    for i, p in enumerate(space.params):
        h = semi_diameters[p.surface - 1] if p.kind in ASPHERE_KINDS else None
        step = float((steps or {}).get(p.name) or default_step(p, x0[i], h)) * step_scale
        deltas = np.array(OFFSETS) * step
        fields = np.full((len(OFFSETS), len(nominal_fields)), math.nan)
        failed = []
        for k, d in enumerate(deltas):
            x = x0.copy()
            x[i] += d
            try:
                fields[k] = evaluate_fields(merit, space.apply(base, x), apertures)
            except Exception as exc:
                if not _is_design_error(exc):
                    raise
                failed.append(f"{d:+.4g}: {_reason(exc)}")
            done += 1
            if progress:
                progress(done, total)
        ab = [_fit(deltas, fields[:, f] - nominal_fields[f]) for f in range(len(nominal_fields))]
        a = np.array([v[0] for v in ab])
        b = np.array([v[1] for v in ab])
        rows.append(ParamSensitivity(p, float(x0[i]), step, deltas, fields, nominal_fields, a, b, failed))
    return Sensitivity(space, list(merit.fields), nominal_fields, rows, step_scale)


# ----- budget -> ranges ------------------------------------------------------------------
@dataclass
class Allocation:
    name: str
    share_um: float  # this parameter's RSS share of the budget
    tolerance: float  # proposed half-width (parameter units)
    capped: bool  # the share was not reached within the cap
    cap: float
    lo: float  # proposed range
    hi: float
    growth_model_um: float  # model growth over [lo, hi]
    growth_traced_um: float = math.nan  # traced worst-field growth, max of the two ends
    traced_ends_um: tuple = (math.nan, math.nan)  # traced worst-field RMS at lo, hi (inf: failed)
    traced_failed: list = field(default_factory=list)  # reasons of failed ends


def _physical(p: Parameter, lo: float, hi: float, nominal: float) -> tuple[float, float]:
    if p.kind == "radius":
        if nominal > 0:
            lo = max(lo, 1e-3 * nominal)
        else:
            hi = min(hi, 1e-3 * nominal)
    elif p.kind in ("thickness", "f_number", "epd"):
        lo = max(lo, 1e-3 * nominal)
    elif p.kind == "air_gap":
        lo = max(lo, 0.0)
    return lo, hi


def _solve_tolerance(r: ParamSensitivity, share: float, cap: float) -> tuple[float, bool]:
    if r.growth(cap) < share:
        return cap, True
    lo, hi = 0.0, cap
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if r.growth(mid) < share:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * cap:
            break
    return hi, False


def allocate(
    sens: Sensitivity,
    budget_um: float,
    given: ParameterSpace | None = None,
    merit: Merit | None = None,
    lens: "Lens | dict | None" = None,
    apertures: str = "free",
) -> list:
    """Tolerances from an RSS-shared budget (see the module doc).  ``given`` (default: the
    analysed space) supplies the caps and the ranges the proposal is cut to.  With ``merit``
    and ``lens`` the two ends of each proposed range are traced (``growth_traced_um``)."""
    if not (isinstance(budget_um, (int, float)) and math.isfinite(budget_um) and budget_um > 0):
        raise InputError(f"budget must be a positive number of um, got {budget_um!r}")
    check_apertures(apertures)
    given = given or sens.space
    bounds = {p.name: p for p in given.params}
    share = budget_um / math.sqrt(len(sens.rows))
    out = []
    base = Lens.load(lens).data if lens is not None else None
    for r in sens.rows:
        g = bounds.get(r.param.name, r.param)
        inside = g.min <= r.nominal <= g.max
        cap = max(r.nominal - g.min, g.max - r.nominal) if inside else 0.5 * (g.max - g.min)
        t, capped = _solve_tolerance(r, share, cap)
        lo, hi = r.nominal - t, r.nominal + t
        if inside:
            lo, hi = max(lo, g.min), min(hi, g.max)
        lo, hi = _physical(r.param, lo, hi, r.nominal)
        al = Allocation(r.param.name, share, t, capped, cap, lo, hi, r.growth_range(lo, hi))
        if merit is not None and base is not None:
            x0 = np.array(sens.space.values(base), float)
            i = sens.space.names.index(r.param.name)
            ends = []
            for v in (lo, hi):
                x = x0.copy()
                x[i] = v
                try:
                    ends.append(float(evaluate_fields(merit, sens.space.apply(base, x), apertures).max()))
                except Exception as exc:
                    if not _is_design_error(exc):
                        raise
                    ends.append(math.inf)
                    al.traced_failed.append(f"{r.param.name} = {v:.6g}: {_reason(exc)}")
            al.traced_ends_um = tuple(ends)
            al.growth_traced_um = max(0.0, max(ends) - sens.nominal_worst)
        out.append(al)
    return out


def rss(values) -> float:
    v = np.asarray([x for x in values if math.isfinite(x)], float)
    return float(np.sqrt(np.sum(v**2)))


def model_worst(sens: Sensitivity, values: np.ndarray) -> np.ndarray:
    """Worst-field RMS (um) of designs ``values`` (n, P) by the separable model: each
    field's nominal plus the sum over parameters of its quadratic change (no interaction
    terms).  Compared with the traced Monte Carlo it shows what the one-at-a-time models
    miss."""
    x = np.atleast_2d(np.asarray(values, float))
    d = x - np.array([r.nominal for r in sens.rows])[None, :]
    a = np.stack([r.a for r in sens.rows])  # (P, F)
    b = np.stack([r.b for r in sens.rows])
    per_field = sens.nominal_fields[None, :] + d @ a + (d**2) @ b
    return per_field.max(axis=1)


def proposed_space(
    sens: Sensitivity,
    alloc: list,
    given: ParameterSpace | None = None,
    source: str = "<proposed>",
    description: str | None = None,
) -> ParameterSpace:
    """The proposed ranges as a space: same names, kinds, surfaces, units, notes and
    constraints as ``given`` (default: the analysed space)."""
    given = given or sens.space
    by = {a.name: a for a in alloc}
    params = [
        Parameter(p.name, p.kind, p.surface, float(by[p.name].lo), float(by[p.name].hi), p.unit)
        for p in sens.space.params
    ]
    return ParameterSpace(
        params,
        source=source,
        lens_ref=given.lens_ref,
        description=description,
        notes=given.notes,
        constraints=given.constraints,
    )


# ----- Monte Carlo -----------------------------------------------------------------------
@dataclass
class MonteCarlo:
    space: ParameterSpace
    values: np.ndarray  # (n, P) drawn parameter values (accepted, in draw order)
    fields: np.ndarray  # (n, F) per-field RMS (um); NaN for failed designs
    spec_um: float
    failures: dict  # reason -> count
    sampling: dict  # sample_designs summary (drawn, rejected by reason)
    seed: int
    failed_index: list = field(default_factory=list)

    @property
    def n(self) -> int:
        return int(len(self.values))

    @property
    def worst(self) -> np.ndarray:
        """Worst-field RMS per design; +inf for failed designs."""
        w = np.nanmax(np.where(np.isnan(self.fields), -np.inf, self.fields), axis=1)
        return np.where(np.isfinite(w), w, np.inf)

    @property
    def n_failed(self) -> int:
        return int(sum(self.failures.values()))

    @property
    def yield_(self) -> float:
        return float(np.mean(self.worst <= self.spec_um)) if self.n else math.nan

    @property
    def yield_stderr(self) -> float:
        y = self.yield_
        return math.sqrt(y * (1.0 - y) / self.n) if self.n else math.nan

    def percentiles(self, qs=(5, 25, 50, 75, 90, 95, 99)) -> dict:
        w = self.worst
        ok = w[np.isfinite(w)]
        if not len(ok):
            return {f"p{q}": math.nan for q in qs}
        # failed designs count as +inf (above every traced one); percentiles are order
        # statistics ("higher"), so they stay finite while fewer than 100 - q % failed
        out = {f"p{q}": float(np.percentile(w, q, method="higher")) for q in qs}
        out["min"] = float(ok.min())
        out["max_traced"] = float(ok.max())
        return out

    def summary(self) -> dict:
        return {
            "n": self.n,
            "seed": self.seed,
            "spec_um": self.spec_um,
            "yield": self.yield_,
            "yield_stderr": self.yield_stderr,
            "n_failed": self.n_failed,
            "failures": dict(self.failures),
            "worst_rms_percentiles_um": self.percentiles(),
            "mean_worst_rms_um": float(np.mean(self.worst[np.isfinite(self.worst)]))
            if np.any(np.isfinite(self.worst))
            else math.nan,
            "sampling": self.sampling,
        }


def monte_carlo(
    space: ParameterSpace,
    lens: "Lens | dict",
    merit: Merit,
    n: int,
    spec_um: float,
    seed: int = 0,
    limits=None,
    progress: Callable[[int, int], None] | None = None,
    apertures: str = "free",
) -> MonteCarlo:
    """``n`` manufacturable designs drawn uniformly from ``space`` (every parameter at once),
    traced; yield = fraction with worst-field RMS <= ``spec_um``.  ``limits``: a
    :class:`optix_e2e.lens_design.constraints.Limits` (default: the space's ``[constraints]``)."""
    from .constraints import Limits
    from .sampling import sample_designs

    check_apertures(apertures)
    lens = Lens.load(lens)
    if limits is None:
        limits = Limits.from_dict(space.constraints, f"{space.source}: [constraints]")
    # checked as traced (the one definition of lens_design.constraints)
    rule = "auto" if apertures == "free" else "fixed"
    res = sample_designs(space, lens, n, seed=seed, method="uniform", limits=limits, apertures=rule)
    fields = np.full((len(res.values), len(merit.fields)), math.nan)
    failures: dict = {}
    failed_index = []
    for j, x in enumerate(res.values):
        try:
            fields[j] = evaluate_fields(merit, space.apply(lens.data, x), apertures)
        except Exception as exc:
            if not _is_design_error(exc):
                raise
            why = _reason(exc)
            failures[why] = failures.get(why, 0) + 1
            failed_index.append(j)
        if progress:
            progress(j + 1, len(res.values))
    samp = {k: v for k, v in res.summary().items() if k not in ("parameters", "space")}
    return MonteCarlo(space, res.values, fields, float(spec_um), failures, samp, seed, failed_index)
