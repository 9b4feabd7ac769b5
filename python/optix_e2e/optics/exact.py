"""Exact optics inside the loop: the engine's PSFs and relative illumination of a design, and
their derivatives with respect to the lens parameters, as a torch autograd Function.

Why central differences (and not forward-mode derivatives through the trace and the pupil
function): the engine computes a design's K fields x RGB PSFs in milliseconds and runs many
designs in parallel in one call, so the 2P + 1 designs of a central-difference Jacobian
(P = 19 in the paper-triplet e2e space: 39 designs) are one batch. Everything the dataset does
to a design comes with it unchanged, refocusing included (the closed-form best focus of
lens_design/focus.py is a smooth function of the lens), so the gradient is that of exactly the
PSFs the surrogate was trained to imitate. Forward-mode would need dual numbers through the
ray trace, the aiming, the focus, the pupil sampling, the FFT and the resampling of the Rust
engine: a second engine to keep right.

The step of each parameter is chosen, not guessed (``choose_steps``): the central difference
D(h) = (f(x + h) - f(x - h)) / 2h has a truncation error ~ h^2 f''' / 6 and a round-off error
~ eps |f| / h (here "round-off" is everything in the engine that is not smooth at tiny scales:
pupil sampling, method switches of the ``auto`` PSF, float32 PSFs). On a geometric ladder of
steps, |D(h_j) - D(h_{j+1})| estimates the error at h_j: it falls as h^2 while truncation rules
and rises as 1/h once round-off does; the step where it is smallest balances the two, and that
difference is the stated error of the derivative.

A design the engine rejects is never a NaN or a silent zero: the centre design rejected is an
``EngineRejectedDesign`` naming the parameters and the engine's reason; one side of a
difference rejected (a design next to a limit) gives the one-sided difference of the other side
(counted in ``ExactOptics.last``); both sides rejected is the same named error, naming the
parameter.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..surrogate.data import bin_psf
from ..surrogate.ground_truth import EngineRejectedDesign
from ..surrogate.ground_truth import exact_arrays
from ..errors import InputError


@dataclass
class StepChoice:
    """The chosen central-difference step of each parameter (its units), the ladder it came
    from (fractions of each parameter's range) and the estimated relative error there."""

    names: list[str]
    steps: np.ndarray
    ladder: list[float]
    rel_error: np.ndarray  # |D(h_j) - D(h_j+1)| / |D(h_j)| at the chosen j, per parameter
    curves: np.ndarray  # [P, L - 1]: that estimate at every rung

    def to_json(self) -> dict:
        """JSON-safe: an estimate no rung gave (the engine rejected its designs) is null."""

        def num(x):
            return float(x) if np.isfinite(x) else None

        return {
            "names": self.names,
            "steps": [float(s) for s in self.steps],
            "ladder": self.ladder,
            "rel_error": [num(e) for e in self.rel_error],
            "curves": [[num(c) for c in row] for row in self.curves],
        }

    @classmethod
    def from_json(cls, d: dict) -> "StepChoice":
        def arr(x):
            return np.array([np.inf if e is None else e for e in x], float)

        return cls(
            list(d["names"]),
            np.array(d["steps"], float),
            list(d["ladder"]),
            arr(d["rel_error"]),
            np.array([arr(row) for row in d["curves"]]),
        )


def unrenderable(manifest: dict, values, min_energy: float = 0.9) -> str | None:
    """Why the design ``values`` [P] cannot be rendered on the manifest's terms cheaply (None
    if it can): its refocused RMS spot (3 sigma) wider than half the PSF window at some field;
    the engine's FFT refusing it (its fast path; the ``auto`` method would fall back to the
    Huygens PSF, about a minute a design: a design run's Jacobian takes 2P + 1); or less than
    ``min_energy`` of the flux inside the window at some field and channel."""
    from ..dataset.manifest import nearest_image_plane, refocused_designs, space_and_base
    from ..lens import Lens
    from ..lens_design.focus import refocus_many
    from ..surrogate.ground_truth import exact_arrays

    v = np.asarray(values, np.float64).reshape(1, -1)
    _, base = space_and_base(manifest)
    d = refocused_designs(manifest, v, [float(base.data["surfaces"][-1]["thickness"])])[0]
    err = refocus_many([d], "best", base.fields_deg, base.wavelengths_nm, base.wavelength_weights)[0]
    if err:
        return f"the engine cannot refocus it ({err})"
    nearest = nearest_image_plane(manifest)  # the dataset's focus rule (focus_within)
    if nearest is not None and float(d["surfaces"][-1]["thickness"]) < nearest:
        d["surfaces"][-1]["thickness"] = nearest
    half = 0.5 * float(manifest["settings"]["window_um"])
    try:
        lens = Lens(d)
    except InputError as err:  # e.g. surfaces crossing in the beam (no manufacturable design does)
        return f"not a lens ({err})"
    for f in (0.0, float(max(manifest["fields_deg"]))):
        rms = float(lens.spot(f)["rms_um"])
        if not 3 * rms <= half:
            return f"RMS spot {rms:.1f} um at {f:g} deg: 3 sigma exceeds half the {2 * half:g} um PSF window"
    fast = {**manifest, "settings": {**manifest["settings"], "psf_method": "fft"}}
    arrays, meta = exact_arrays(fast, v)
    if meta["n_failed"]:
        return f"the engine's FFT refuses it ({meta['failures'][0]['reason'][:160]})"
    e = float(np.min(arrays["energy_in_window"]))
    if e < min_energy:
        return f"only {e:.2f} of the flux inside the PSF window at its worst field"
    return None


@dataclass
class ExactOptics:
    """The engine on a surrogate's (or a dataset manifest's) terms: ``psfs(values)`` and
    ``jacobian(values)`` for raw parameter values [P] (float64 numpy)."""

    manifest: dict
    psf_kind: str = "psf_sensor"
    bin: int = 1
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    steps: np.ndarray | None = None  # per parameter (None: choose_steps on first use)
    step_choice: StepChoice | None = None
    last: dict = field(default_factory=dict)  # what the last call did: designs, seconds, one-sided
    designs_computed: int = 0
    seconds: float = 0.0  # engine time of every call so far
    _cache: tuple | None = None  # (values bytes, psf, vig) of the last design computed

    @classmethod
    def from_surrogate(cls, sur) -> "ExactOptics":
        if not sur.manifest:
            raise InputError("exact optics need the surrogate's dataset manifest (its space, fields and settings)")
        return cls(
            sur.manifest,
            sur.psf_kind,
            sur.bin,
            sur.param_min.double().cpu().numpy(),
            sur.param_max.double().cpu().numpy(),
        )

    @property
    def names(self) -> list[str]:
        return [p["name"] for p in self.manifest["space"]["parameters"]]

    def _range(self) -> tuple[np.ndarray, np.ndarray]:
        if self.lo is None:
            ps = self.manifest["space"]["parameters"]
            self.lo = np.array([p["min"] for p in ps], float)
            self.hi = np.array([p["max"] for p in ps], float)
        return self.lo, self.hi

    def _run(self, values: np.ndarray) -> tuple[list, list, dict]:
        """PSFs [K, C, S, S] and vignetting [K, C] of each design (None where rejected), reasons."""
        t0 = time.perf_counter()
        arrays, meta = exact_arrays(self.manifest, values)
        self.designs_computed += len(values)
        self.seconds += time.perf_counter() - t0
        psf = [None] * len(values)
        vig = [None] * len(values)
        for j, i in enumerate(arrays["design"]):
            psf[int(i)] = np.asarray(bin_psf(arrays[self.psf_kind][j], self.bin), np.float64)
            vig[int(i)] = np.asarray(arrays["relative_illumination"][j], np.float64)
        reasons = {int(f["design"]): f["reason"] for f in meta["failures"]}
        return psf, vig, reasons

    def _rejected(self, values: np.ndarray, reason: str) -> EngineRejectedDesign:
        vals = ", ".join(f"{n}={v:.6g}" for n, v in zip(self.names, values))
        return EngineRejectedDesign(f"the engine rejects the design ({reason}); parameters: {vals}")

    def psfs(self, values) -> tuple[np.ndarray, np.ndarray]:
        """(psf [K, C, S, S], vignetting [K, C]) of one design; EngineRejectedDesign if rejected."""
        v = np.asarray(values, np.float64).reshape(1, -1)
        if self._cache is not None and self._cache[0] == v.tobytes():
            self.last = {"designs": 0, "seconds": 0.0, "one_sided": []}
            return self._cache[1], self._cache[2]
        t0 = time.perf_counter()
        psf, vig, reasons = self._run(v)
        self.last = {"designs": 1, "seconds": time.perf_counter() - t0, "one_sided": []}
        if psf[0] is None:
            raise self._rejected(v[0], reasons.get(0, "engine error"))
        self._cache = (v.tobytes(), psf[0], vig[0])
        return psf[0], vig[0]

    def jacobian(self, values) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(psf, vignetting, dpsf/dv [P, K, C, S, S], dvig/dv [P, K, C]) at one design, by
        central differences with ``steps`` (chosen here on first use), all 2P + 1 designs in one
        parallel engine call."""
        v = np.asarray(values, np.float64).reshape(-1)
        if self.steps is None:
            self.step_choice = choose_steps(self, v)
            self.steps = self.step_choice.steps
        lo, hi = self._range()
        p = len(v)
        h = self.steps
        # the sides inside the ranges (a side beyond a bound is not computed: one-sided there)
        tol = 1e-12 * (hi - lo)
        sides = [
            (i, s)
            for s in (1.0, -1.0)
            for i in range(p)
            if (v[i] + h[i] <= hi[i] + tol[i] if s > 0 else v[i] - h[i] >= lo[i] - tol[i])
        ]
        rows = [v] + [v + s * h[i] * np.eye(p)[i] for i, s in sides]
        t0 = time.perf_counter()
        psf, vig, reasons = self._run(np.stack(rows))
        if psf[0] is None:
            raise self._rejected(v, reasons.get(0, "engine error"))
        at = {side: 1 + k for k, side in enumerate(sides)}  # (parameter, sign) -> row
        jp = np.empty((p, *psf[0].shape))
        jv = np.empty((p, *vig[0].shape))
        one_sided = []
        for i in range(p):
            ku, kd = at.get((i, 1.0)), at.get((i, -1.0))
            up = ku is not None and psf[ku] is not None
            dn = kd is not None and psf[kd] is not None
            if up and dn:
                jp[i] = (psf[ku] - psf[kd]) / (2 * h[i])
                jv[i] = (vig[ku] - vig[kd]) / (2 * h[i])
            elif up or dn:
                k, s = (ku, 1.0) if up else (kd, -1.0)
                jp[i] = s * (psf[k] - psf[0]) / h[i]
                jv[i] = s * (vig[k] - vig[0]) / h[i]
                one_sided.append(self.names[i])
            else:
                why = (
                    "; ".join(reasons[k] for k in (ku, kd) if k is not None and k in reasons)
                    or "both outside the parameter's range"
                )
                raise EngineRejectedDesign(
                    f"no derivative in {self.names[i]}: the designs at "
                    f"{self.names[i]} = {v[i]:.6g} +- {h[i]:.3g} are both rejected ({why})"
                )
        self.last = {"designs": len(rows), "seconds": time.perf_counter() - t0, "one_sided": one_sided}
        self._cache = (v.reshape(1, -1).tobytes(), psf[0], vig[0])
        return psf[0], vig[0], jp, jv


def choose_steps(
    engine: ExactOptics, values, ladder: tuple[float, ...] = (3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5)
) -> StepChoice:
    """Each parameter's central-difference step from a ladder of fractions of its range (one
    engine call of 2 P L designs): the rung where successive estimates agree best, i.e. where
    truncation (~h^2) and round-off (~1/h) balance. A rung whose designs the engine rejects
    is skipped."""
    v = np.asarray(values, np.float64).reshape(-1)
    lo, hi = engine._range()
    width = hi - lo
    p, n_l = len(v), len(ladder)
    rows = []
    for _j, frac in enumerate(ladder):
        for s in (1.0, -1.0):
            rows.append(v[None] + s * np.diag(frac * width))
    psf, vig, _ = engine._run(np.concatenate(rows))

    def at(j, s, i):  # the design of rung j, side s (0: +, 1: -), parameter i
        k = (2 * j + s) * p + i
        return None if psf[k] is None else np.concatenate([psf[k].ravel(), vig[k].ravel()])

    steps = np.empty(p)
    rel = np.empty(p)
    curves = np.full((p, n_l - 1), np.inf)
    for i in range(p):
        d = []
        for j, frac in enumerate(ladder):
            a, b = at(j, 0, i), at(j, 1, i)
            d.append(None if a is None or b is None else (a - b) / (2 * frac * width[i]))
        for j in range(n_l - 1):
            if d[j] is not None and d[j + 1] is not None:
                curves[i, j] = np.abs(d[j] - d[j + 1]).sum() / max(np.abs(d[j]).sum(), 1e-300)
        j = int(np.argmin(curves[i])) if np.isfinite(curves[i]).any() else n_l // 2
        steps[i], rel[i] = ladder[j] * width[i], curves[i, j]
    return StepChoice(engine.names, steps, list(ladder), rel, curves)


class _ExactPSF(torch.autograd.Function):
    """values [P] -> (psf [K, C, S, S], vignetting [K, C]) from the engine; backward by the
    central-difference Jacobian computed in the same forward call."""

    @staticmethod
    def forward(ctx, values, engine):
        v = values.detach().double().cpu().numpy()
        if values.requires_grad:
            psf, vig, jp, jv = engine.jacobian(v)
            # the Jacobian goes to the values' device with the PSFs: one copy per call
            ctx.save_for_backward(torch.as_tensor(jp, device=values.device), torch.as_tensor(jv, device=values.device))
        else:
            psf, vig = engine.psfs(v)
        ctx.dtype = values.dtype
        # copies: the engine's arrays stay in its cache
        return (
            torch.tensor(psf, dtype=values.dtype, device=values.device),
            torch.tensor(vig, dtype=values.dtype, device=values.device),
        )

    @staticmethod
    def backward(ctx, g_psf, g_vig):
        jp, jv = ctx.saved_tensors
        g = (jp * g_psf.double()).flatten(1).sum(1) + (jv * g_vig.double()).flatten(1).sum(1)
        return g.to(dtype=ctx.dtype), None


def exact_psfs(values: torch.Tensor, engine: ExactOptics) -> tuple[torch.Tensor, torch.Tensor]:
    """Differentiable exact optics: raw lens parameters [P] -> (psf [K, C, S, S] unit sum per
    channel, vignetting [K, C]), gradients by the engine's central differences."""
    return _ExactPSF.apply(values, engine)
