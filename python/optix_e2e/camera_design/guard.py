"""The manufacturability guard of a design run (paper Sec. 5.2: the limits hold for every lens
the run visits): the dataset's limits (centre and edge thickness, air gaps, back focus; the
space file's [constraints]) as a check and as margins on parameter values, and the rule that
keeps each optimizer step inside them (project the step along the limits it leans across,
then cut it back). A step the guard changed is counted in history.csv's ``cut``.

Two modes (``DesignConfig.guard``): ``project`` repairs a lens step after Adam has taken it;
``barrier`` also steers before it: a log barrier on the margins closer than ``band`` mm to
their bound adds its gradient to the lens's (the margins' slopes by forward differences, one
margin evaluation per parameter), so Adam's moments carry the lens along or away from a limit
instead of into it, step after step."""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import nnls

from ..dataset.manifest import space_and_base
from ..lens_design.constraints import Limits, Manufacturability
from ..optics import DifferentiableOptics
from .outputs import design_lens

GUARD_MODES = ("project", "barrier")


class Manufacturable:
    """The dataset's manufacturability limits (the space file's [constraints]) on parameter
    values, by the one definition the sampler used (lens_design.constraints: each design at
    its own clear apertures): ``problems(values)`` lists the violated ones (empty:
    manufacturable), ``margins(values)`` each limit's slack. The image plane at the base
    lens's distance, as the sampler checks (the BFD limit is far from binding here)."""

    def __init__(self, manifest: dict):
        self.manifest = manifest
        self.rule = Manufacturability(Limits.from_dict(manifest.get("sampling_summary", {}).get("limits")))
        self.limits = self.rule.limits
        _, base = space_and_base(manifest)
        self.image_distance = float(base.data["surfaces"][-1]["thickness"])

    @property
    def checks(self) -> int:
        return self.rule.checks

    def problems(self, values) -> list[str]:
        return self.rule.problems(design_lens(self.manifest, np.asarray(values, np.float64), self.image_distance))

    def margins(self, values) -> np.ndarray:
        """Each limit's value minus its bound (mm; >= 0 where met), in a fixed order."""
        return self.rule.margins(design_lens(self.manifest, np.asarray(values, np.float64), self.image_distance))


def _values(optics: DifferentiableOptics, u: torch.Tensor) -> np.ndarray:
    return (optics.lo + (optics.hi - optics.lo) * torch.sigmoid(u)).detach().double().cpu().numpy()


def _margin_slopes(optics, guard: Manufacturable, u: torch.Tensor, m0: np.ndarray, rows: np.ndarray, h: float):
    """d margin / d u for the margins ``rows`` (m0: all margins at u), by forward differences:
    one margin evaluation per parameter. Raises where a shifted point cannot be sized."""
    jac = np.empty((rows.size, u.numel()))
    for k in range(u.numel()):
        du = torch.zeros_like(u)
        du[k] = h
        jac[:, k] = (guard.margins(_values(optics, u + du))[rows] - m0[rows]) / h
    return jac


def project_step(
    optics: DifferentiableOptics,
    u_prev: torch.Tensor,
    step: torch.Tensor,
    guard: Manufacturable,
    h: float = 1e-3,
    near_mm: float = 0.05,
) -> torch.Tensor:
    """The step with its components across the limits it would break removed: the limits
    within ``near_mm`` of their bound at u_prev, linearized by forward differences in u
    (one margin evaluation per parameter), and the step projected onto {J d >= -m}
    (least-distance projection, active set by nonnegative least squares). Where the engine
    cannot trace one of those points, the step is returned unchanged and the caller cuts it
    back along itself (``problems`` calls such a point unmanufacturable)."""
    try:
        m0 = guard.margins(_values(optics, u_prev))
        m1 = guard.margins(_values(optics, u_prev + step))
        active = np.flatnonzero((m0 < near_mm) | (m1 < 0))
        if active.size == 0:
            return step
        jac = _margin_slopes(optics, guard, u_prev, m0, active, h)
    except Exception:  # untraceable (a ray misses a surface, surfaces cross): no linearization here
        return step
    d = step.double().cpu().numpy()
    # min |d' - d|^2 s.t. J d' >= -m0: d' = d + J^T lam, lam >= 0 minimizing |J J^T lam - (-m0 - J d)|
    lam, _ = nnls(jac @ jac.T + 1e-12 * np.eye(active.size), np.maximum(-m0[active] - jac @ d, 0.0))
    return torch.as_tensor(d + jac.T @ lam, dtype=step.dtype, device=step.device)


def keep_manufacturable(
    optics: DifferentiableOptics, u_prev: torch.Tensor, guard: Manufacturable, iters: int = 12, project: bool = True
) -> bool:
    """After an optimizer step: if the new lens parameters break a manufacturability limit,
    the step is projected along the limits it leans across (``project_step``: the lens slides
    along an active limit instead of stopping at it), then, if the projected step still
    breaks one (the limits curve), cut back along it to the farthest manufacturable point
    (bisection; the previous point is manufacturable). Returns True when the step changed."""
    u_new = optics.u.detach().clone()
    if not guard.problems(optics.values().detach().cpu().numpy()):
        return False
    if project:
        u_new = u_prev + project_step(optics, u_prev, u_new - u_prev, guard)
        with torch.no_grad():
            optics.u.copy_(u_new)
        if not guard.problems(optics.values().detach().cpu().numpy()):
            return True
    lo, hi = 0.0, 1.0
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        with torch.no_grad():
            optics.u.copy_(u_prev + mid * (u_new - u_prev))
        if guard.problems(optics.values().detach().cpu().numpy()):
            hi = mid
        else:
            lo = mid
    with torch.no_grad():
        optics.u.copy_(u_prev + lo * (u_new - u_prev))
    return True


def barrier_gradient(
    optics: DifferentiableOptics, guard: Manufacturable, band: float, weight: float, h: float = 1e-3
) -> tuple[torch.Tensor, float]:
    """The gradient in u of B = weight * sum over the margins m < band that the lens
    parameters move of (m / band - 1 - log(m / band)) (zero with a zero slope at the band,
    infinite at the bound), and B itself. A margin no parameter moves (a fixed element's
    thickness) cannot be steered and is left out; one at or below zero (a point the cut-back
    will repair) counts as 1e-6 mm. Zero where no margin is inside the band or the design
    cannot be sized."""
    u = optics.u.detach()
    zero = (torch.zeros_like(u), 0.0)
    try:
        m0 = guard.margins(_values(optics, u))
        near = np.flatnonzero(m0 < band)
        if near.size == 0:
            return zero
        jac = _margin_slopes(optics, guard, u, m0, near, h)
    except Exception:  # noqa: BLE001 - cannot be sized here: the cut-back handles this step
        return zero
    moved = np.any(jac != 0.0, axis=1)
    if not moved.any():
        return zero
    m, jac = np.maximum(m0[near][moved], 1e-6), jac[moved]
    value = weight * float(np.sum(m / band - 1.0 - np.log(m / band)))
    dB_dm = weight * (1.0 / band - 1.0 / m)  # < 0: the barrier falls as a margin grows
    return torch.as_tensor(jac.T @ dB_dm, dtype=u.dtype, device=u.device), value
