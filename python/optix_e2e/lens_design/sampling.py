"""Seeded sampling of designs from a parameter space, with manufacturability checks.

Candidates are drawn in blocks from a uniform, scrambled Sobol (:mod:`.sobol`, scipy's bits
without its import) or Latin-hypercube (scipy.stats.qmc) sequence over the space's box, checked, and the first ``n`` that pass are
kept in draw order, so a seed gives the same designs on every machine.  Rejected
candidates are counted by reason (a candidate may fail several checks; each is counted).

Each candidate is checked as the engine will trace it (the base lens with the dataset's
aperture setting, ``apertures``) at its own clear apertures, by the one definition of a
manufacturable lens (:mod:`optix_e2e.lens_design.constraints`), which the design run's guard
and final checks use too. ``apertures="base-lens"`` is the rule of the datasets made before
that definition (the base lens's clear semi-diameters for every design), kept to reproduce them.
"""

from __future__ import annotations

import copy
import csv
import io
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..io import write_text_atomic
from ..lens import Lens
from ..lens.apertures import engine_base
from .constraints import REASONS, Limits, Manufacturability, check_design, reason_of
from .constraints import apertures as clear_apertures
from .sobol import ScrambledSobol
from .space import ParameterSpace, SpaceError

METHODS = ("uniform", "sobol", "lhs")
#: candidates checked at a time (on two threads) before they are taken in draw order
CHUNK = 32
APERTURE_RULES = ("auto", "fixed", "base-lens")


def _unit_block(method: str, d: int, m: int, seed: int, state: dict) -> np.ndarray:
    """The next ``m`` points of the seeded sequence in [0, 1)^d."""
    if "engine" not in state:
        if method == "uniform":
            state["engine"] = np.random.Generator(np.random.PCG64(seed))
        elif method == "sobol":
            state["engine"] = ScrambledSobol(d, seed)
        elif method == "lhs":
            from scipy.stats import qmc

            state["engine"] = qmc.LatinHypercube(d, seed=np.random.default_rng(seed))
        else:
            raise InputError(f"unknown sampling method {method!r} (one of {', '.join(METHODS)})")
    eng = state["engine"]
    if method == "uniform":
        return eng.random((m, d))
    if method == "sobol":  # balance holds for 2^k points: the first block, then doubling
        done = int(eng.num_generated)
        return eng.random(done if done else 2 ** max(0, math.ceil(math.log2(m))))
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
    apertures: str = "auto"

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
            "apertures": self.apertures,
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
    apertures: str = "auto",
    field_fold: bool = True,
) -> SampleResult:
    """``n`` manufacturable designs (parameter value rows) from ``space`` over ``base``,
    each checked as traced with the dataset's aperture setting ``apertures`` ("auto": no
    clear apertures, "fixed": the base lens's but the stop's) at its own clear apertures.
    ``field_fold=False`` leaves the check that the image of the field does not fold out (to
    study such designs: benches/ri_fold_check.py)."""
    if n < 1:
        raise InputError(f"n must be >= 1, got {n}")
    if method not in METHODS:
        raise InputError(f"unknown sampling method {method!r} (one of {', '.join(METHODS)})")
    if apertures not in APERTURE_RULES:
        raise InputError(f"unknown aperture rule {apertures!r} (one of {', '.join(APERTURE_RULES)})")
    limits = limits or Limits()
    max_draws = max_draws or max(1000, 100 * n)
    lo = np.array([p.min for p in space.params])
    span = np.array([p.max - p.min for p in space.params])
    if apertures == "base-lens":  # the datasets made before the one definition
        data, sd = base.data, clear_apertures(base)

        def problems(d):
            return check_design(d, sd, limits)
    else:
        data, problems = engine_base(base, apertures), Manufacturability(limits, field_fold).problems
        bad = [p for p in problems(copy.deepcopy(data)) if p.startswith("untraceable")]
        if bad:  # e.g. a lens whose beam its clear apertures keep off crossing rims
            raise SpaceError(
                f"{space.source}: the base lens {base.name} cannot be traced with apertures={apertures!r} "
                f"({bad[0]}); sample as its dataset traces it (apertures='fixed' keeps its clear apertures)"
            )
    rejected = {r: 0 for r in REASONS}
    accepted: list[np.ndarray] = []
    drawn = n_rej = 0
    state: dict = {}
    # Candidates are checked CHUNK at a time on two threads (the engine's checks release the
    # GIL, so one candidate's trace runs beside another's Python) and taken in draw order, so
    # the designs, counts and the point where drawing stops are those of one-at-a-time checks
    # (a chunk's candidates past the n-th accepted are checked and dropped, not counted).
    with ThreadPoolExecutor(max_workers=2) as pool:
        while len(accepted) < n:
            if drawn >= max_draws:
                raise SpaceError(
                    f"{space.source}: only {len(accepted)} of {n} designs pass the manufacturability "
                    f"checks after {drawn} candidates (rejections: "
                    + ", ".join(f"{k} {v}" for k, v in rejected.items() if v)
                    + "); widen the ranges or relax the limits"
                )
            block = _unit_block(method, len(space), n if method == "sobol" else n - len(accepted), seed, state)
            for lo_k in range(0, len(block), CHUNK):
                if len(accepted) == n or drawn >= max_draws:
                    break
                xs = [lo + u * span for u in block[lo_k : lo_k + min(CHUNK, max_draws - drawn)]]
                checked = pool.map(lambda x: problems(space.apply(data, x)), xs)
                for x, reasons in zip(xs, checked):
                    if len(accepted) == n:
                        break
                    drawn += 1
                    if reasons:
                        n_rej += 1
                        for r in {reason_of(r) for r in reasons}:
                            rejected[r] += 1
                    else:
                        accepted.append(x)
                    if progress:
                        progress(drawn, len(accepted))
    return SampleResult(space, np.array(accepted), drawn, rejected, n_rej, limits, method, seed, apertures)


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
    write_text_atomic(path, buf.getvalue())


def read_designs_csv(path: "str | Path", names: Sequence[str]) -> np.ndarray:
    """The (n, P) values of a designs.csv whose header lists ``names``."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows or rows[0] != ["design", *names]:
        raise SpaceError(f"{path}: header does not list the parameters {', '.join(names)}")
    return np.array([[float(v) for v in r[1:]] for r in rows[1:]], float).reshape(len(rows) - 1, len(names))
