"""Seeded sampling of designs from a parameter space, with manufacturability checks.

Candidates are drawn in blocks from a uniform, scrambled Sobol or Latin-hypercube
sequence over the space's box (scipy.stats.qmc), checked, and the first ``n`` that pass are
kept in draw order, so a seed gives the same designs on every machine.  Rejected
candidates are counted by reason (a candidate may fail several checks; each is counted).

Checks (limits from the space file's ``[constraints]`` table, or arguments):

* ``center_thickness`` / ``edge_thickness``: glass center and rim thickness >= limits,
* ``air_gap``: air between optical surfaces at the center and at the rim >= limit, and a
  separate stop plane clear of its neighbours' rims,
* ``back_focal_distance``: last vertex to image >= limit,
* ``surfaces_cross``: consecutive surfaces never cross anywhere inside their apertures,
* ``aperture_outside_surface``: a clear semi-diameter beyond a conic's reach (or the
  sphere's radius).

Apertures are the base lens's clear semi-diameters (the physical parts keep their size),
or, where it gives none, its ray footprint.
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..lens import Lens
from .optimizer import Constraints
from .space import ParameterSpace, SpaceError
from ..lens.surface import sag
from ..errors import InputError

METHODS = ("uniform", "sobol", "lhs")
REASONS = (
    "center_thickness",
    "edge_thickness",
    "air_gap",
    "back_focal_distance",
    "surfaces_cross",
    "aperture_outside_surface",
)
_ROW_REASON = {
    "center_thickness": "center_thickness",
    "edge_thickness": "edge_thickness",
    "air_gap_center": "air_gap",
    "air_gap_edge": "air_gap",
    "stop_clearance": "air_gap",
    "back_focal_distance": "back_focal_distance",
}


@dataclass
class Limits:
    """Manufacturability limits (mm); ``None`` = not checked."""

    min_center: float | None = None
    min_edge: float | None = None
    min_air_gap: float | None = None
    min_bfd: float | None = None

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "constraints") -> "Limits":
        d = dict(d or {})
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise SpaceError(
                f"{source}: unknown constraint(s) {', '.join(unknown)} (known: {', '.join(cls.__dataclass_fields__)})"
            )
        for k, v in d.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise SpaceError(f"{source}: {k} must be a finite number >= 0, got {v!r}")
        return cls(**{k: float(v) for k, v in d.items()})

    def merged(self, **override) -> "Limits":
        return Limits(**{**asdict(self), **{k: v for k, v in override.items() if v is not None}})


def apertures(lens: Lens) -> np.ndarray:
    """Clear semi-diameters used for the checks: the prescription's, else the ray footprint."""
    from .report import footprint

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
    """Reasons (from :data:`REASONS`) why the lens dict ``design`` is not manufacturable;
    empty when it passes."""
    bad = geometry_problem(design, semi_diameters)
    if bad is not None and bad[0] == "aperture_outside_surface":
        return [bad[0]]
    reasons: list[str] = [bad[0]] if bad else []
    rows = Constraints(
        min_center=limits.min_center, min_edge=limits.min_edge, min_air_gap=limits.min_air_gap, min_bfd=limits.min_bfd
    ).evaluate(design, {}, semi_diameters)
    for row in rows:
        reason = _ROW_REASON[row["name"].split("[")[0]]
        if not row["ok"] and reason not in reasons:
            reasons.append(reason)
    return reasons


def _unit_block(method: str, d: int, m: int, seed: int, state: dict) -> np.ndarray:
    """The next ``m`` points of the seeded sequence in [0, 1)^d."""
    from scipy.stats import qmc

    if "engine" not in state:
        if method == "uniform":
            state["engine"] = np.random.Generator(np.random.PCG64(seed))
        elif method == "sobol":
            state["engine"] = qmc.Sobol(d, scramble=True, seed=np.random.default_rng(seed))
        elif method == "lhs":
            state["engine"] = qmc.LatinHypercube(d, seed=np.random.default_rng(seed))
        else:
            raise InputError(f"unknown sampling method {method!r} (one of {', '.join(METHODS)})")
    eng = state["engine"]
    if method == "uniform":
        return eng.random((m, d))
    if method == "sobol":  # balance holds for 2^k points: the first block, then doubling
        done = int(eng.num_generated)
        return eng.random(done) if done else eng.random_base2(max(0, math.ceil(math.log2(m))))
    return eng.random(m)


@dataclass
class SampleResult:
    space: ParameterSpace
    values: np.ndarray  # (n, d) accepted parameter values, in draw order
    drawn: int  # candidates drawn
    rejected: dict  # reason -> count
    n_rejected: int  # candidates failing at least one check
    limits: Limits
    method: str
    seed: int

    def summary(self) -> dict:
        return {
            "accepted": int(len(self.values)),
            "drawn": self.drawn,
            "rejected": self.n_rejected,
            "rejected_by_reason": dict(self.rejected),
            "acceptance_rate": len(self.values) / max(1, self.drawn),
            "method": self.method,
            "seed": self.seed,
            "limits": asdict(self.limits),
            "space": self.space.source,
            "parameters": self.space.names,
        }


def sample_designs(
    space: ParameterSpace,
    base: Lens,
    n: int,
    seed: int = 0,
    method: str = "sobol",
    limits: Limits | None = None,
    max_draws: int | None = None,
    progress=None,
) -> SampleResult:
    """``n`` manufacturable designs (parameter value rows) from ``space`` over ``base``."""
    if n < 1:
        raise InputError(f"n must be >= 1, got {n}")
    if method not in METHODS:
        raise InputError(f"unknown sampling method {method!r} (one of {', '.join(METHODS)})")
    limits = limits or Limits()
    max_draws = max_draws or max(1000, 100 * n)
    lo = np.array([p.min for p in space.params])
    span = np.array([p.max - p.min for p in space.params])
    sd = apertures(base)
    data = base.data
    rejected = {r: 0 for r in REASONS}
    accepted: list[np.ndarray] = []
    drawn = n_rej = 0
    state: dict = {}
    while len(accepted) < n:
        if drawn >= max_draws:
            raise SpaceError(
                f"{space.source}: only {len(accepted)} of {n} designs pass the manufacturability "
                f"checks after {drawn} candidates (rejections: "
                + ", ".join(f"{k} {v}" for k, v in rejected.items() if v)
                + "); widen the ranges or relax the limits"
            )
        block = _unit_block(method, len(space), n if method == "sobol" else n - len(accepted), seed, state)
        for u in block:
            if len(accepted) == n or drawn >= max_draws:
                break
            drawn += 1
            x = lo + u * span
            reasons = check_design(space.apply(data, x), sd, limits)
            if reasons:
                n_rej += 1
                for r in reasons:
                    rejected[r] += 1
            else:
                accepted.append(x)
            if progress:
                progress(drawn, len(accepted))
    return SampleResult(space, np.array(accepted), drawn, rejected, n_rej, limits, method, seed)


def write_designs_csv(path: "str | Path", names: Sequence[str], values: np.ndarray) -> None:
    """designs.csv: a header ``design, <parameter names>`` and one row per design (its
    index and the values at full precision), written to a temporary file and renamed, so
    a reader never sees half a file."""
    path = Path(path)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["design", *names])
    for i, row in enumerate(values):
        w.writerow([i, *(repr(float(v)) for v in row)])
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(buf.getvalue(), encoding="utf-8", newline="")
    os.replace(tmp, path)


def read_designs_csv(path: "str | Path", names: Sequence[str]) -> np.ndarray:
    """The (n, P) values of a designs.csv whose header lists ``names``."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows or rows[0] != ["design", *names]:
        raise SpaceError(f"{path}: header does not list the parameters {', '.join(names)}")
    return np.array([[float(v) for v in r[1:]] for r in rows[1:]], float).reshape(len(rows) - 1, len(names))
