"""Global search for a nominal design (the role of Zemax's Global Search and Hammer).

The local optimizer (:func:`optix_e2e.lens_design.optimizer.polish`, damped least squares) finds
the minimum of the basin it starts in.  This search visits many basins, in rounds:

* **explore** (Global Search): scrambled Sobol' points over the variables' ranges
  (``scipy.stats.qmc``), each screened by one merit evaluation; the best of each batch are
  polished.
* **hammer** (Hammer): from the best basins found so far, random jumps of a size that
  adapts (it grows while jumps fall back into the basin they left and shrinks while they
  land in worse ones), each polished.

Every polish runs in a worker process (``workers``; the CLI's default is one per core, at
most one per polish of a round), with the same
merit, constraints and bounds as ``optix lens optimize``.  A round's starts come from the
seed and the basins known when the round begins, so a search with a fixed number of
rounds repeats exactly; a time budget stops it where it is (each polish then returns the
best point it reached).  Polished points within ``same_basin`` (largest difference of a
unit-range variable) of a known basin count as a visit of that basin.

The search works on any ``problem`` with ``n``, ``u0`` and ``evaluate(u) -> (residuals,
report)`` (report: ``merit`` and ``constraints`` rows, or None for a rejected design).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np

from ..errors import InputError, RunError
from .optimizer import polish

__all__ = ["Basin", "GlobalResult", "basins_csv", "global_search"]

ACTIVE_MM = 0.01  # an inequality constraint this close to its limit is "active" (binding)


@dataclass
class Basin:
    """One local minimum: where it is (unit coordinates), its merit, its constraints."""

    u: list
    cost: float  # sum of squared residuals (merit and constraint terms)
    merit: float  # the merit alone (um of RMS spot, waves of RMS OPD)
    feasible: bool  # every constraint met
    min_slack: float | None  # smallest (value - limit) of the inequality constraints
    tightest: str | None  # ... which constraint
    active: list  # inequality constraints within ACTIVE_MM of their limit
    efl_error: float | None  # relative EFL error
    found_by: str  # "start", "explore <k>", "hammer <basin> (step s)"
    round: int
    visits: int = 1
    nfev: int = 0

    def key(self) -> tuple:
        """Ordering: feasible designs first, then the lower merit (infeasible: cost)."""
        return (0, self.merit) if self.feasible else (1, self.cost)


@dataclass
class GlobalResult:
    best: Basin
    basins: list  # every distinct basin, best first
    rounds: int
    polishes: int
    nfev: int
    wall_s: float
    stopped: str  # "rounds" or "time budget"
    history: list = field(default_factory=list)  # (wall_s, best merit) when the best changed

    def summary(self) -> dict:
        return {
            "rounds": self.rounds,
            "polishes": self.polishes,
            "basins_found": len(self.basins),
            "nfev": self.nfev,
            "wall_s": self.wall_s,
            "stopped_by": self.stopped,
            "best": asdict(self.best),
            "basins": [asdict(b) for b in self.basins],
            "best_history": self.history,
        }


def _basin(problem, u, nfev, found_by, rnd) -> Basin:
    r, rep = problem.evaluate(u)
    cost = float(r @ r)
    if rep is None:
        return Basin(
            u=list(map(float, u)),
            cost=cost,
            merit=math.inf,
            feasible=False,
            min_slack=None,
            tightest=None,
            active=[],
            efl_error=None,
            found_by=found_by,
            round=rnd,
            nfev=nfev,
        )
    slack = [(c["value"] - c["limit"], c["name"]) for c in rep["constraints"] if "limit" in c]
    efl = [c for c in rep["constraints"] if c["name"] == "efl"]
    low = min(slack) if slack else (None, None)
    return Basin(
        u=list(map(float, u)),
        cost=cost,
        merit=float(rep["merit"]),
        feasible=all(c["ok"] for c in rep["constraints"]),
        min_slack=None if low[0] is None else float(low[0]),
        tightest=low[1],
        active=[name for v, name in slack if v <= ACTIVE_MM],
        efl_error=float((efl[0]["value"] - efl[0]["target"]) / efl[0]["target"]) if efl else None,
        found_by=found_by,
        round=rnd,
        nfev=nfev,
    )


# ----- worker side -----------------------------------------------------------------------
_PROBLEM = None


def _init_worker(problem) -> None:
    global _PROBLEM
    _PROBLEM = problem


def _polish_task(u0, max_nfev, deadline_wall, found_by, rnd, problem=None) -> Basin:
    """Polish one start; ``deadline_wall`` is a time.time() (shared across processes)."""
    problem = problem if problem is not None else _PROBLEM
    deadline = None
    if deadline_wall is not None:
        deadline = time.monotonic() + max(0.0, deadline_wall - time.time())
    u, nfev, _ = polish(problem, u0, max_nfev=max_nfev, deadline=deadline)
    return _basin(problem, u, nfev, found_by, rnd)


# ----- the search ------------------------------------------------------------------------
def global_search(
    problem,
    *,
    minutes: float | None = 10.0,
    rounds: int | None = None,
    seed: int = 0,
    workers: int = 2,
    batch: int = 4,
    screen: int = 16,
    polish_nfev: int = 300,
    step: float = 0.1,
    same_basin: float = 0.02,
    include_start: bool = True,
    progress: Callable[[Basin, "GlobalResult"], None] | None = None,
) -> GlobalResult:
    """Search ``problem`` for its best basin.

    Each round polishes ``batch`` starts (half explore, half hammer once a basin is known;
    ``screen`` Sobol' candidates screened per explore start), ``polish_nfev`` evaluations
    each.  Stops after ``rounds`` rounds or ``minutes`` (whichever first; one must be set).
    Round 0 polishes the start itself (``include_start``), so the result is never worse
    than the local optimizer from the same start given the same evaluations.
    ``progress(basin, state)`` is called after each polish.
    """
    from scipy.stats import qmc

    if minutes is None and rounds is None:
        raise InputError("global search: give a time budget (minutes) and/or a number of rounds")
    if batch < 1 or workers < 1 or screen < 1:
        raise InputError("global search: batch, workers and screen must be >= 1")
    t0 = time.time()
    deadline = None if minutes is None else t0 + 60.0 * minutes
    rng = np.random.default_rng(seed)
    sobol = qmc.Sobol(problem.n, scramble=True, seed=rng)
    basins: list[Basin] = []
    state = GlobalResult(best=None, basins=basins, rounds=0, polishes=0, nfev=0, wall_s=0.0, stopped="rounds")
    n_explore = 0

    def add(b: Basin) -> None:
        if b.nfev == 0 and basins:
            return  # queued past the time budget: never polished, not a basin
        state.polishes += 1
        state.nfev += b.nfev
        best_before = basins[0].key() if basins else None
        ub = np.asarray(b.u)
        for i, k in enumerate(basins):
            if np.max(np.abs(np.asarray(k.u) - ub)) <= same_basin:
                k.visits += 1
                if b.key() < k.key():  # the same basin, reached deeper: keep its provenance
                    basins[i] = replace(b, found_by=k.found_by, round=k.round, visits=k.visits, nfev=k.nfev)
                break
        else:
            basins.append(b)
        basins.sort(key=Basin.key)
        if best_before is None or basins[0].key() < best_before:
            state.history.append((time.time() - t0, basins[0].merit))
        state.best = basins[0]
        state.wall_s = time.time() - t0
        if progress:
            progress(b, state)

    def starts(rnd: int) -> list[tuple]:
        nonlocal n_explore, step
        out = []
        if rnd == 0 and include_start:
            out.append((np.asarray(problem.u0, float), "start"))
        n_hammer = 0 if not basins else batch // 2
        while len(out) < batch - n_hammer:
            if deadline is not None and time.time() >= deadline and out:
                break
            cand = sobol.random(screen)
            costs = []
            for c in cand:
                r, _ = problem.evaluate(c)
                costs.append(float(r @ r))
            n_explore += 1
            out.append((cand[int(np.argmin(costs))], f"explore {n_explore}"))
        top = basins[: max(1, min(3, len(basins)))]
        for j in range(n_hammer):
            home = top[j % len(top)]
            u = np.clip(np.asarray(home.u) + rng.normal(0.0, step, problem.n), 0.0, 1.0)
            out.append((u, f"hammer from merit {home.merit:.6g} (step {step:.3g})"))
        return out

    pool = None
    if workers > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        pool = ProcessPoolExecutor(
            max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init_worker, initargs=(problem,)
        )
    try:
        rnd = 0
        while rounds is None or rnd < rounds:
            if deadline is not None and time.time() >= deadline:
                state.stopped = "time budget"
                break
            jobs = starts(rnd)
            if pool is not None:
                futures = [pool.submit(_polish_task, u, polish_nfev, deadline, tag, rnd) for u, tag in jobs]
                results = [f.result() for f in futures]
            else:
                results = [_polish_task(u, polish_nfev, deadline, tag, rnd, problem=problem) for u, tag in jobs]
            known = [np.asarray(b.u) for b in basins]
            best_before = basins[0].key() if basins else None
            for b in results:
                add(b)
            # adapt the hammer's step: jumps that fall back home -> longer; into worse -> shorter
            hammers = [b for b in results if b.found_by.startswith("hammer")]
            if hammers:
                back = sum(any(np.max(np.abs(np.asarray(b.u) - k)) <= same_basin for k in known) for b in hammers)
                better = best_before is not None and basins[0].key() < best_before
                if back > len(hammers) // 2:
                    step = min(0.5, 1.5 * step)
                elif not better:
                    step = max(0.01, step / 1.25)
            rnd += 1
            state.rounds = rnd
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
    state.wall_s = time.time() - t0
    if state.best is None:
        raise RunError("global search: the time budget ended before the first polish")
    return state


def basins_csv(summary: dict) -> str:
    """The basins of a ``GlobalResult.summary()`` (as ``optix lens optimize --global`` writes
    it) as CSV, best first: one row per basin, the variables' values last."""
    import csv
    import io

    basins = summary["basins"]
    names = list(basins[0].get("values", {})) if basins else []
    out = io.StringIO()
    w = csv.writer(out)
    w.writerow(
        [
            "rank",
            "merit",
            "feasible",
            "min_slack_mm",
            "tightest",
            "n_active",
            "efl_error",
            "found_by",
            "round",
            "visits",
            "nfev",
            *names,
        ]
    )
    for k, b in enumerate(basins, 1):
        merit = b["merit"] if b["merit"] is not None else math.inf
        w.writerow(
            [
                k,
                f"{merit:.6g}",
                b["feasible"],
                "" if b["min_slack"] is None else f"{b['min_slack']:.6g}",
                b["tightest"] or "",
                len(b["active"]) if "active" in b else "",
                "" if b["efl_error"] is None else f"{b['efl_error']:.3e}",
                b["found_by"],
                b["round"],
                b["visits"],
                b["nfev"],
                *(f"{b['values'][n]:.10g}" for n in names),
            ]
        )
    return out.getvalue()
