"""The manufacturability guard's two modes (camera_design/guard.py): ``project`` repairs a lens
step after Adam took it; ``barrier`` also steers Adam before it with a log barrier on the
margins near their bounds. From the e2e nominal, which sits on its edge-thickness limit, a
task gradient that keeps leaning across the limit gets most steps cut back under ``project``
and few under ``barrier``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optix_e2e.camera_design.build import load_surrogate
from optix_e2e.camera_design.guard import Manufacturable, barrier_gradient, keep_manufacturable
from optix_e2e.optics import DifferentiableOptics

BAND, WEIGHT = 0.25, 1e-3


@pytest.fixture(scope="module")
def e2e():
    sur = load_surrogate("paper-triplet-e2e")
    return sur, Manufacturable(sur.manifest)


def _margin(optics, guard) -> float:
    """The first element's edge-thickness margin (mm; the second of the margins' fixed order:
    the binding one at the e2e nominal; lens 2's centre, fixed at its 2 mm limit, is constant)."""
    return float(guard.margins(optics.values().detach().double().numpy())[1])


def test_the_barrier_gradient_is_the_slope_of_the_barrier(e2e):
    sur, guard = e2e
    optics = DifferentiableOptics(sur)
    assert _margin(optics, guard) < 0.01  # the nominal on its limit
    grad, value = barrier_gradient(optics, guard, BAND, WEIGHT)
    assert value > 0 and grad.norm() > 0
    # central difference of the barrier along its gradient (the margins' slopes inside are
    # forward differences with h = 1e-3: agreement to a few percent)
    u0, d, h = optics.u.detach().clone(), grad / grad.norm(), 2e-3
    vals = []
    for s in (h, -h):
        with torch.no_grad():
            optics.u.copy_(u0 + s * d)
        vals.append(barrier_gradient(optics, guard, BAND, WEIGHT)[1])
    assert (vals[0] - vals[1]) / (2 * h) == pytest.approx(grad.norm().item(), rel=0.05)
    # and descending it moves the lens off the limit
    with torch.no_grad():
        optics.u.copy_(u0 - 0.05 * d)
    assert _margin(optics, guard) > 0.001


def test_no_barrier_away_from_the_limits(e2e):
    sur, guard = e2e
    optics = DifferentiableOptics(sur)
    grad, value = barrier_gradient(optics, guard, band=1e-6, weight=WEIGHT)
    assert value == 0.0 and torch.count_nonzero(grad) == 0


def _cut_steps(sur, guard, barrier: bool, steps: int = 12) -> tuple[int, float]:
    """Adam (lr 1e-2, the runs' lens rate) on a constant task gradient whose descent leans
    across the active limit; the guard after each step. (Cut steps, distance moved in u.)"""
    optics = DifferentiableOptics(sur)
    u0 = optics.u.detach().clone()
    grad, _ = barrier_gradient(optics, guard, BAND, WEIGHT)
    across = grad / grad.norm()  # the barrier grows along it: towards the bound
    g = torch.Generator().manual_seed(3)
    # a task gradient whose descent leans across the limit (minus ``across``), with a random part
    task = -0.05 * (across + 0.5 * torch.randn(u0.shape, generator=g) / np.sqrt(u0.numel()))
    adam = torch.optim.Adam([optics.u], lr=1e-2)
    cuts = 0
    for _ in range(steps):
        adam.zero_grad()
        optics.u.grad = task.clone().to(optics.u)
        if barrier:
            b, _ = barrier_gradient(optics, guard, BAND, WEIGHT)
            optics.u.grad += b.to(optics.u)
        before = optics.u.detach().clone()
        adam.step()
        cuts += keep_manufacturable(optics, before, guard)
        assert guard.problems(optics.values().detach().numpy()) == []
    return cuts, (optics.u.detach() - u0).norm().item()


def test_the_barrier_steers_where_projection_keeps_cutting(e2e):
    sur, guard = e2e
    cut_project, moved_project = _cut_steps(sur, guard, barrier=False)
    cut_barrier, moved_barrier = _cut_steps(sur, guard, barrier=True)
    assert cut_project >= 8, cut_project  # leaning across the limit: nearly every step repaired
    assert cut_barrier <= 3, cut_barrier
    assert moved_barrier > 0.02  # and the lens still moves
