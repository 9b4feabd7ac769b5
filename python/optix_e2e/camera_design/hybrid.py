"""The optics model in the loop, checked along the way (issue 20): ``--optics surrogate | exact |
hybrid``.

Every ``check_every`` optimizer steps, and after the last, the exact engine computes the
current design's PSFs (one design: milliseconds) and the error of the optics model the steps
are using is logged per field (the PSF relative L1 of unit-sum PSFs, median over channels; the
surrogate's evaluation measure) to TensorBoard and results.json, with the plain network's error
beside it.

* ``surrogate``: the paper's way; the checks only measure.
* ``exact``: the engine's PSFs and central-difference gradients (optics/exact.py) in every
  optics step; the checks measure what the network would have been off by.
* ``hybrid``: the surrogate, kept honest. When a check finds the model's worst field above
  ``threshold``, the model is refined at the current design: ``refine = "correction"`` (the
  default) adds exact minus surrogate there to the network's output (an additive, zeroth-order
  multi-fidelity correction: exact at the anchor, the network's change away from it; one
  engine design), ``"network"`` fine-tunes the network on a few hundred engine designs about it
  (surrogate/refine.py). If the next check finds the refined model above the threshold again,
  the refinement does not hold over ``check_every`` steps: the optics steps fall back to exact
  gradients until a check finds the model (refined at the check before) back under.
  Every refinement and switch is an event in the log.

The error reported for the final design is that of the model the last steps used, measured
before any refinement there (a refinement at the final design would make it zero by
construction).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from ..errors import InputError
from ..surrogate.refine import RefineSettings, refine_around
from .config import REFINE_MODES, task_default


def psf_errors(psf: torch.Tensor, psf_true: torch.Tensor) -> list[float]:
    """PSF relative L1 per field, median over channels: [K, C, S, S] x 2 -> K floats (the
    results' ``surrogate_psf_rel_l1_per_field`` measure, in double precision)."""
    from .outputs import psf_rel_l1_per_field

    return psf_rel_l1_per_field(psf.double(), psf_true.double())


def exact_gradient_steps(history: list[dict]) -> int:
    """How many of a training's steps moved the lens on the engine's gradients."""
    return sum(h.get("optics") == "exact" and h["block"] in ("optics", "all") for h in history)


class OpticsModeMismatch(InputError):
    """A run resumed under another optics model than it was started with (not damage)."""


class OpticsMonitor:
    """Checks (and, in hybrid mode, keeps) the optics model of a DifferentiableOptics."""

    def __init__(
        self,
        optics,
        mode: str,
        every: int,
        threshold: float = 0.02,
        refine: str = "correction",
        refine_settings: RefineSettings = RefineSettings(),
        writer=None,
        name: str = "end_to_end",
        log=None,
    ):
        if mode not in ("surrogate", "exact", "hybrid"):
            raise InputError(f"optics must be surrogate, exact or hybrid here, got {mode!r}")
        if refine not in REFINE_MODES:
            raise InputError(f"refine must be one of {', '.join(REFINE_MODES)}, got {refine!r}")
        if every < 1 or not threshold > 0:
            raise InputError(f"check_every >= 1 and hybrid_threshold > 0 required (got {every}, {threshold})")
        self.optics, self.mode, self.every, self.threshold = optics, mode, int(every), float(threshold)
        self.refine, self.refine_settings = refine, refine_settings
        self.writer, self.name, self.log = writer, name, log
        self.checks: list[dict] = []
        self.events: list[dict] = []
        self.refined_at_last_check = False
        self.refine_seconds = 0.0
        optics.backend = "exact" if mode == "exact" else "surrogate"

    def due(self, step: int, total: int) -> bool:
        return step % self.every == 0 or step == total

    @torch.no_grad()
    def _model_psfs(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The surrogate (with its correction, if any) at the current design."""
        return self.optics._surrogate_psfs()

    def check(self, step: int, final: bool = False) -> dict:
        t0 = time.perf_counter()
        optics = self.optics
        if not optics.surrogate.has_network:  # exact optics on a space no network learned (paper-doublet)
            return self._engine_only(step, t0)
        values = optics.values().detach().double().cpu().numpy()
        # the engine's PSFs (CPU) go to the optics' device once per check
        psf_x, vig_x = (torch.as_tensor(a, device=optics.lo.device) for a in optics.exact.psfs(values))
        with torch.no_grad():
            net_psf, _ = optics.surrogate.psfs(optics.values().detach(), check=False)
            model_psf, model_vig = self._model_psfs()
        used = optics.backend
        model_err = psf_errors(model_psf, psf_x)
        rec = {
            "step": int(step),
            "backend": used,
            # the error of the PSFs the steps before this check used (0 for the engine's own)
            "error_per_field": [0.0] * len(model_err) if used == "exact" else model_err,
            "model_error_per_field": model_err,
            "network_error_per_field": psf_errors(net_psf, psf_x),
            "vignetting_abs_error_max": float((model_vig.double() - vig_x.double()).abs().max()),
            "events": [],
        }
        over = max(model_err) > self.threshold
        if self.mode == "hybrid" and not final:
            if over:
                ev = self._refine(step, values, psf_x, vig_x)
                rec["events"].append(ev)
                still_over = max(ev["error_after"]) > self.threshold
                if used == "surrogate" and (self.refined_at_last_check or still_over):
                    optics.backend = "exact"
                    rec["events"].append(
                        self._event(
                            step,
                            "exact_on",
                            f"the refined surrogate did not hold (worst field {max(model_err):.4f} > {self.threshold})",
                        )
                    )
                self.refined_at_last_check = True
            else:
                if used == "exact":
                    optics.backend = "surrogate"
                    rec["events"].append(
                        self._event(
                            step,
                            "exact_off",
                            f"the refined surrogate is back under the threshold (worst field {max(model_err):.4f})",
                        )
                    )
                self.refined_at_last_check = False
        rec["seconds"] = time.perf_counter() - t0
        self.checks.append(rec)
        if self.writer is not None:
            w, n = self.writer, self.name
            w.add_scalar(f"{n}/optics_error/worst_field", max(rec["error_per_field"]), step)
            w.add_scalar(f"{n}/optics_error/median_field", float(np.median(rec["error_per_field"])), step)
            w.add_scalar(f"{n}/network_error/worst_field", max(rec["network_error_per_field"]), step)
            for k, e in enumerate(rec["network_error_per_field"]):
                w.add_scalar(f"{n}/network_error/field_{k:02d}", e, step)
            w.add_scalar(f"{n}/optics_exact_gradients", float(optics.backend == "exact"), step)
        if self.log is not None and rec["events"]:
            for ev in rec["events"]:
                self.log(f"{self.name} step {step}: {ev['event']}: {ev['detail']}")
        return rec

    def _engine_only(self, step: int, t0: float) -> dict:
        """A check where there is no network to measure: the steps used the engine's own PSFs
        (error 0 at every field), so the engine is not asked for them again."""
        rec = {
            "step": int(step),
            "backend": self.optics.backend,
            "error_per_field": [0.0] * len(self.optics.surrogate.fields_deg),
            "model_error_per_field": None,
            "network_error_per_field": None,
            "vignetting_abs_error_max": 0.0,
            "events": [],
            "seconds": time.perf_counter() - t0,
        }
        self.checks.append(rec)
        if self.writer is not None:
            self.writer.add_scalar(f"{self.name}/optics_exact_gradients", float(self.optics.backend == "exact"), step)
        return rec

    def _event(self, step: int, kind: str, detail: str, **extra) -> dict:
        ev = {"step": int(step), "event": kind, "detail": detail, **extra}
        self.events.append(ev)
        return ev

    def _refine(self, step: int, values: np.ndarray, psf_x: torch.Tensor, vig_x: torch.Tensor) -> dict:
        t0 = time.perf_counter()
        optics = self.optics
        before = psf_errors(self._model_psfs()[0], psf_x)
        if self.refine == "correction":
            optics.correction = None
            with torch.no_grad():
                net_psf, net_vig = optics.surrogate.psfs(optics.values().detach(), check=False)
            optics.correction = ((psf_x.float() - net_psf).detach(), (vig_x.float() - net_vig).detach())
            designs = 0
        else:
            optics.correction = None
            rs = self.refine_settings
            seed = rs.seed * 100003 + int(step)
            designs = refine_around(
                optics.surrogate,
                optics.exact,
                values,
                RefineSettings(rs.designs, rs.radius, rs.steps, rs.batch, rs.lr, seed),
            )["designs"]
        after = psf_errors(self._model_psfs()[0], psf_x)
        seconds = time.perf_counter() - t0
        self.refine_seconds += seconds
        return self._event(
            step,
            "refine",
            f"{self.refine} at the current design: worst field {max(before):.4f} -> {max(after):.4f} ({seconds:.1f} s)",
            error_before=before,
            error_after=after,
            engine_designs=designs,
            seconds=seconds,
        )

    # -- resuming ------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything a resumed run needs to continue on the same path: the checks and events,
        the backend and correction in force, and the engine's finite-difference steps (chosen
        once, at the first design that needed a gradient) and its counters."""
        c = self.optics.correction
        ex = self.optics._exact
        engine = (
            None
            if ex is None
            else {
                "steps": None if ex.steps is None else [float(h) for h in ex.steps],
                "step_choice": ex.step_choice.to_json() if ex.step_choice is not None else None,
                "designs_computed": int(ex.designs_computed),
                "seconds": float(ex.seconds),
                "one_pass": int(ex.one_pass),
                "fallbacks": int(ex.fallbacks),
            }
        )
        return {
            "mode": self.mode,
            "refine": self.refine,
            "checks": self.checks,
            "events": self.events,
            "backend": self.optics.backend,
            "refined_at_last_check": self.refined_at_last_check,
            "refine_seconds": self.refine_seconds,
            "correction": None if c is None else [c[0].clone(), c[1].clone()],
            "engine": engine,
        }

    def load_state_dict(self, st: dict) -> None:
        from ..optics.exact import StepChoice

        if st.get("mode", self.mode) != self.mode or (
            self.mode == "hybrid" and st.get("refine", self.refine) != self.refine
        ):
            raise OpticsModeMismatch(
                f"this run was started with optics {st.get('mode')} (refine {st.get('refine')}), not "
                f"{self.mode} (refine {self.refine}): with --optics auto the bundled trade-off has "
                f"changed since; use another --out or --optics {st.get('mode')}"
            )
        self.checks, self.events = list(st["checks"]), list(st["events"])
        self.optics.backend = st["backend"]
        self.refined_at_last_check = bool(st["refined_at_last_check"])
        self.refine_seconds = float(st.get("refine_seconds", 0.0))
        c = st.get("correction")
        dev = self.optics.lo.device
        self.optics.correction = None if c is None else (c[0].to(dev), c[1].to(dev))
        eng = st.get("engine")
        if eng is not None:
            ex = self.optics.exact
            ex.steps = None if eng["steps"] is None else np.array(eng["steps"], float)
            ex.step_choice = None if eng["step_choice"] is None else StepChoice.from_json(eng["step_choice"])
            ex.designs_computed, ex.seconds = int(eng["designs_computed"]), float(eng["seconds"])
            ex.one_pass, ex.fallbacks = int(eng.get("one_pass", 0)), int(eng.get("fallbacks", 0))

    def summary(self) -> dict:
        """For results.json: settings, every check, the events, and the final design's errors."""
        last = self.checks[-1] if self.checks else None
        ex = self.optics.exact if self.optics._exact is not None else None
        return {
            "mode": self.mode,
            "check_every": self.every,
            "threshold": self.threshold,
            "refine": self.refine if self.mode == "hybrid" else None,
            "final_error_per_field": last["error_per_field"] if last else None,
            "final_network_error_per_field": last["network_error_per_field"] if last else None,
            "n_refinements": sum(e["event"] == "refine" for e in self.events),
            "engine_designs": ex.designs_computed if ex is not None else 0,
            "engine_seconds": ex.seconds if ex is not None else 0.0,
            # lens steps on the engine's one-pass gradient, and on differences where it had none
            "exact_gradient": ex.gradient if ex is not None else None,
            "one_pass_gradients": ex.one_pass if ex is not None else 0,
            "difference_fallbacks": ex.fallbacks if ex is not None else 0,
            "refine_seconds": self.refine_seconds,
            "step_choice": ex.step_choice.to_json() if ex is not None and ex.step_choice is not None else None,
            "checks": self.checks,
            "events": self.events,
        }


# --optics auto: the measured trade-off (benches/optics_tradeoff.py writes it; the package ships
# the copy in bundled/), read for the run's task
TRADEOFF_CSV = "optics_tradeoff.csv"
NUMERIC = ("patch", "fields", "psnr_db", "ssim", "wall_s", "psnr_vs_best", "psnr_vs_best_lo", "psnr_vs_best_hi")


def tradeoff_path():
    from pathlib import Path

    return Path(__file__).resolve().parent.parent / "bundled" / TRADEOFF_CSV


def read_tradeoff(path=None) -> list[dict]:
    """The rows of the speed/accuracy table (all columns as written; NUMERIC ones as floats)."""
    import csv

    path = tradeoff_path() if path is None else path
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError:
        return []
    out = []
    for r in rows:
        row = dict(r)
        for k in NUMERIC:
            try:
                row[k] = float(r[k])
            except (KeyError, TypeError, ValueError):
                row[k] = None
        out.append(row)
    return out


def resolve_optics(cfg, path=None) -> tuple[str, dict]:
    """The optics model a run uses, and why (with the hybrid refinement in ``["refine"]``).
    surrogate | exact | hybrid: as asked. auto: among the
    optics models measured for the task (the optics sweep of benches/optics_tradeoff.py), the
    fastest that is not measurably worse than the best: its held-out PSNR under exact optics,
    paired over the same images against the best model's, has a 95 % interval reaching zero.
    The surrogate (the paper's way) where nothing was measured for the task."""
    if cfg.optics != "auto":
        default = task_default(cfg.task, cfg.budget, "optics") == cfg.optics
        why = f"the default for {cfg.task} (docs/optics-in-the-loop.md)" if default else "asked for"
        return cfg.optics, {"requested": cfg.optics, "chosen": cfg.optics, "refine": cfg.refine, "why": why}
    rows = [
        r
        for r in read_tradeoff(path)
        if r.get("task") == cfg.task
        and r.get("sweep") == "optics"
        and r["psnr_db"] is not None
        and r["wall_s"] is not None
        and r["psnr_vs_best_hi"] is not None
    ]
    if not rows:
        return "surrogate", {
            "requested": "auto",
            "chosen": "surrogate",
            "refine": cfg.refine,
            "why": f"no measured trade-off for task {cfg.task}: the surrogate (the paper's way)",
        }
    good = [r for r in rows if r["psnr_vs_best_hi"] >= 0.0]
    pick = min(good, key=lambda r: r["wall_s"])
    best = max(rows, key=lambda r: r["psnr_db"])
    table = {
        r["point"]: {
            "optics": r["optics"],
            "refine": r.get("refine") or None,
            "psnr_db": r["psnr_db"],
            "wall_s": r["wall_s"],
            "psnr_vs_best_ci95": [r["psnr_vs_best_lo"], r["psnr_vs_best_hi"]],
        }
        for r in rows
    }
    return pick["optics"], {
        "requested": "auto",
        "chosen": pick["optics"],
        "refine": pick.get("refine") or cfg.refine,
        "point": pick["point"],
        "table": table,
        "source": TRADEOFF_CSV,
        "why": f"{pick['point']}: the fastest ({pick['wall_s']:.0f} s of training) not measurably worse than the "
        f"best held-out PSNR ({best['point']}, {best['psnr_db']:.2f} dB; paired interval "
        f"[{pick['psnr_vs_best_lo']:+.3f}, {pick['psnr_vs_best_hi']:+.3f}] dB) measured for {cfg.task}",
    }
