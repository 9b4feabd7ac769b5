"""Exact optics inside the loop: the engine's PSFs and relative illumination of a design, and
their derivatives with respect to the lens parameters, as a torch autograd Function.

Two gradients (``ExactOptics.gradient``, the design setting ``exact_gradient``):

* ``"one-pass"`` (the default): the engine's vector-Jacobian product
  (``engine.psf_set_vjp``; crates/psf-engine/src/gradient.rs). The backward pass hands the
  engine dL/dPSF and dL/d(vignetting) and gets dL/d(parameters) back from one pass over the
  design's PSFs: forward-mode tangents through the rays, the fits and the focus, reverse mode
  through the pupil grid, the transforms, the normalization and the sensor binning. Its cost
  does not grow with the number of parameters. It is exact where every PSF of the set comes
  from the fast FFT with fitted pupils (the dataset's usual path); where one does not (``auto``
  chose another method, a fit missed its tolerance, a paraxial refocus, real-ray aiming), the
  engine says so and that step falls back to the differences below, counted in
  ``ExactOptics.fallbacks`` (results.json).
* ``"differences"``: the central-difference Jacobian, 2P + 1 designs in one parallel engine
  call. Everything the dataset does to a design comes with it unchanged, refocusing included
  (the closed-form best focus of lens_design/focus.py is a smooth function of the lens).

The step of each difference is chosen, not guessed (``choose_steps``): the central difference
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

import json
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputError
from ..surrogate.data import bin_psf
from ..surrogate.ground_truth import EngineRejectedDesign, exact_arrays


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


EXACT_GRADIENTS = ("one-pass", "differences")


def engine_parameters(space) -> list[tuple[str, int, int]]:
    """The engine's name of each of a space's parameters (``engine.psf_set_vjp``'s params):
    (kind, surface index from 0, aspheric term index: 0 for r^2, 1 for r^4, ...)."""
    from ..lens_design.space import ASPHERE_KINDS

    out = []
    for p in space.params:
        if p.kind in ("f_number", "epd"):
            out.append((p.kind, 0, 0))
        elif p.kind in ("thickness", "air_gap"):
            out.append(("thickness", p.surface - 1, 0))
        elif p.kind in ("radius", "conic"):
            out.append((p.kind, p.surface - 1, 0))
        else:
            out.append(("aspheric", p.surface - 1, ASPHERE_KINDS[p.kind] // 2 - 1))
    return out


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
    gradient: str = "one-pass"  # EXACT_GRADIENTS: the backward pass's method
    one_pass: int = 0  # backward passes by the engine's one-pass gradient
    fallbacks: int = 0  # ... and by differences where it had none (the last reason in `last`)
    _cache: tuple | None = None  # (values bytes, psf, vig, image distance) of the last design

    def __post_init__(self):
        if self.gradient not in EXACT_GRADIENTS:
            raise InputError(f"exact_gradient must be one of {', '.join(EXACT_GRADIENTS)}, got {self.gradient!r}")

    @classmethod
    def from_surrogate(cls, sur, gradient: str = "one-pass") -> "ExactOptics":
        if not sur.manifest:
            raise InputError("exact optics need the surrogate's dataset manifest (its space, fields and settings)")
        return cls(
            sur.manifest,
            sur.psf_kind,
            sur.bin,
            sur.param_min.double().cpu().numpy(),
            sur.param_max.double().cpu().numpy(),
            gradient=gradient,
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

    def _run(self, values: np.ndarray, image: list | None = None) -> tuple[list, list, dict]:
        """PSFs [K, C, S, S] and vignetting [K, C] of each design (None where rejected), reasons;
        ``image`` gets each design's image distance (mm, None where rejected)."""
        t0 = time.perf_counter()
        arrays, meta = exact_arrays(self.manifest, values)
        self.designs_computed += len(values)
        self.seconds += time.perf_counter() - t0
        psf = [None] * len(values)
        vig = [None] * len(values)
        if image is not None:
            image[:] = [None] * len(values)
        for j, i in enumerate(arrays["design"]):
            psf[int(i)] = np.asarray(bin_psf(arrays[self.psf_kind][j], self.bin), np.float64)
            vig[int(i)] = np.asarray(arrays["relative_illumination"][j], np.float64)
            if image is not None:
                image[int(i)] = float(arrays["image_distance"][j])
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
        image: list = []
        psf, vig, reasons = self._run(v, image)
        self.last = {"designs": 1, "seconds": time.perf_counter() - t0, "one_sided": []}
        if psf[0] is None:
            raise self._rejected(v[0], reasons.get(0, "engine error"))
        self._cache = (v.tobytes(), psf[0], vig[0], image[0])
        return psf[0], vig[0]

    def vjp(self, values, g_psf, g_vig) -> np.ndarray:
        """dL/d(values) [P] at one design from dL/dpsf [K, C, S, S] and dL/dvignetting [K, C]:
        the engine's one-pass gradient, or, where it has none for this design (``last["fallback"]``
        says why), the central-difference Jacobian's product."""
        v = np.asarray(values, np.float64).reshape(-1)
        g_psf = np.asarray(g_psf, np.float64)
        g_vig = np.asarray(g_vig, np.float64)
        if self.gradient == "one-pass":
            grad, why = self._one_pass(v, g_psf, g_vig)
            if grad is not None:
                self.one_pass += 1
                return grad
            self.fallbacks += 1
        else:
            why = None
        _, _, jp, jv = self.jacobian(v)
        self.last["fallback"] = why
        return (jp * g_psf).reshape(len(v), -1).sum(1) + (jv * g_vig).reshape(len(v), -1).sum(1)

    def _one_pass(self, v: np.ndarray, g_psf: np.ndarray, g_vig: np.ndarray) -> tuple[np.ndarray | None, str | None]:
        """The engine's gradient at ``v``, or (None, why not)."""
        from .. import engine
        from ..dataset.manifest import nearest_image_plane, refocused_designs, space_and_base
        from ..dataset.settings import DatasetSettings
        from ..dataset.shards import focus_points

        self.psfs(v)  # the design and its image distance (cached: the forward pass's)
        z = self._cache[3]
        man = self.manifest
        s = DatasetSettings.of_manifest(man["settings"])
        space, _ = space_and_base(man)
        nearest = nearest_image_plane(man)
        if s.focus == "paraxial":
            return None, "the paraxial refocus has no tangents here (focus = best or fixed)"
        # the image plane follows the best focus unless it sits at the back-focus limit
        clamped = nearest is not None and z <= nearest + 1e-12
        focus = None
        if s.focus == "best" and not clamped:
            fields, wls = focus_points(man)
            focus = (fields, [(wl, 1.0) for wl in wls], int(s.focus_rings))
        # dL/d(the engine's PSFs) before this surrogate's binning: binning's transpose
        sensor = self.psf_kind == "psf_sensor"
        g = torch.as_tensor(g_psf)
        if self.bin > 1:
            k = self.bin
            g = g.repeat_interleave(k, -2).repeat_interleave(k, -1)
        lens = refocused_designs(man, v[None], [z])[0]
        t0 = time.perf_counter()
        try:
            r = self._engine_vjp(man, s, space, lens, g, g_vig, sensor, focus)
        except engine.ArgumentError:
            raise  # ours to fix (shapes, names): not a property of the design
        except engine.EngineError as err:  # the forward pass computed this design: differences can
            return None, f"the engine's one-pass gradient failed ({err})"
        dt = time.perf_counter() - t0
        self.seconds += dt
        self.last = {"designs": 0, "seconds": dt, "one_sided": [], "fallback": r["fallback"]}
        if r["fallback"] is not None:
            return None, r["fallback"]
        grad = np.asarray(r["grad"], np.float64)
        if not np.isfinite(grad).all():
            return None, "the one-pass gradient is not finite"
        return grad, None

    @staticmethod
    def _engine_vjp(man, s, space, lens, g, g_vig, sensor, focus) -> dict:
        from .. import engine

        return engine.psf_set_vjp(
            lens_json=json.dumps(lens),
            fields_deg=[float(f) for f in man["fields_deg"]],
            channels=[[(float(a), float(b)) for a, b in c] for c in man["channels"]],
            params=engine_parameters(space),
            g_psf=np.ascontiguousarray(g.numpy(), np.float64),
            g_ri=np.ascontiguousarray(g_vig, np.float64),
            method=s.psf_method,
            pixel_um=s.pixel_um,
            size=s.size,
            pupil_samples=s.pupil_samples,
            aiming=s.aiming,
            accuracy=s.accuracy,
            sensor=(s.sensor_pixel_um, s.sensor_size) if sensor else None,
            focus=focus,
        )

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
        image: list = []
        psf, vig, reasons = self._run(np.stack(rows), image)
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
        self._cache = (v.reshape(1, -1).tobytes(), psf[0], vig[0], image[0])
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
    engine's one-pass gradient (``engine.gradient == "one-pass"``: one engine call in the
    backward pass) or by the central-difference Jacobian computed in the same forward call."""

    @staticmethod
    def forward(ctx, values, engine):
        v = values.detach().double().cpu().numpy()
        ctx.engine, ctx.values, ctx.jacobian = engine, v, None
        if values.requires_grad and engine.gradient == "differences":
            psf, vig, jp, jv = engine.jacobian(v)
            # the Jacobian goes to the values' device with the PSFs: one copy per call
            ctx.jacobian = (torch.as_tensor(jp, device=values.device), torch.as_tensor(jv, device=values.device))
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
        if ctx.jacobian is not None:
            jp, jv = ctx.jacobian
            g = (jp * g_psf.double()).flatten(1).sum(1) + (jv * g_vig.double()).flatten(1).sum(1)
            return g.to(dtype=ctx.dtype), None
        g = ctx.engine.vjp(ctx.values, g_psf.detach().double().cpu().numpy(), g_vig.detach().double().cpu().numpy())
        return torch.as_tensor(g, dtype=ctx.dtype, device=g_psf.device), None


def exact_psfs(values: torch.Tensor, engine: ExactOptics) -> tuple[torch.Tensor, torch.Tensor]:
    """Differentiable exact optics: raw lens parameters [P] -> (psf [K, C, S, S] unit sum per
    channel, vignetting [K, C]), gradients by the engine (``engine.gradient``)."""
    return _ExactPSF.apply(values, engine)
