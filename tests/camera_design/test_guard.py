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


def test_old_run_folders_keep_the_projection(tmp_path):
    """guard's default became "barrier" and train_positions' "radius" (2026-11-27): a run folder
    made under "project", or before the settings existed (no key in its config.json), resumes
    with the projection (and, without train_positions, with batches uniform over the frame)."""

    from optix_e2e.camera_design.config import check_run_dir, make_config, run_dir_settings

    today = make_config("smoke")
    assert today.guard == "barrier"
    check_run_dir(tmp_path / "a", make_config("smoke", guard="project"))
    older = tmp_path / "b"
    _made_before(older, make_config("smoke", guard="project"), "guard", "train_positions")
    assert run_dir_settings(older, today).train_positions == "frame"  # its batches were drawn so
    assert run_dir_settings(tmp_path / "a", today).train_positions == "radius"
    for run in (tmp_path / "a", older):
        kept = run_dir_settings(run, today)
        assert kept.guard == "project"
        check_run_dir(run, kept)  # accepted: it resumes as it was made
        with pytest.raises(ValueError, match="guard"):
            check_run_dir(run, today)
    check_run_dir(tmp_path / "c", today)
    assert run_dir_settings(tmp_path / "c", today).guard == "barrier"


def test_exact_optics_are_the_image_quality_default_and_a_surrogate_run_folder_resumes_as_made(tmp_path):
    """optics' default became "exact" for the image-quality tasks (2026-11-27; detection keeps
    its surrogate in smoke runs, and since issue 35 moves in the wide detection space on exact
    optics at quick and full): a run folder made under the surrogate default, or before the
    setting existed, resumes on the surrogate; one made on exact keeps exact."""

    from optix_e2e.camera_design.config import check_run_dir, make_config, run_dir_settings

    for budget in ("smoke", "quick", "full"):
        assert make_config(budget).optics == "exact"
        assert make_config(budget, task="low-light").optics == "exact"
        det = make_config(budget, task="detection")
        if budget == "smoke":
            assert (det.optics, det.space) == ("surrogate", "")
        else:
            assert (det.optics, det.space) == ("exact", "paper-triplet-detect-wide")
    today = make_config("smoke")
    check_run_dir(tmp_path / "old", make_config("smoke", optics="surrogate"))
    kept = run_dir_settings(tmp_path / "old", today)
    assert kept.optics == "surrogate"
    check_run_dir(tmp_path / "old", kept)
    with pytest.raises(ValueError, match="optics: 'surrogate' -> 'exact'"):
        check_run_dir(tmp_path / "old", today)
    check_run_dir(tmp_path / "new", today)
    assert run_dir_settings(tmp_path / "new", today).optics == "exact"
    older = tmp_path / "older"  # made before the optics setting existed: it ran on the surrogate
    _made_before(older, make_config("smoke", optics="surrogate"), "optics")
    assert run_dir_settings(older, today).optics == "surrogate"
    check_run_dir(older, run_dir_settings(older, today))
    det = make_config("smoke", task="detection")
    check_run_dir(tmp_path / "det", det)
    assert run_dir_settings(tmp_path / "det", det) == det


def test_a_detection_run_folder_made_before_lens_steps_resumes_on_adams_own_steps(tmp_path):
    """lens_steps = "range" became the detection budgets' default on 2026-11-28: a detection run
    folder made before (no lens_steps in its config.json) resumes as it ran, on Adam's steps in
    u ("sigmoid"); a new one gets "range"; the image-quality tasks keep "sigmoid"."""

    from optix_e2e.camera_design.config import check_run_dir, make_config, run_dir_settings

    for budget in ("smoke", "quick", "full"):
        assert make_config(budget, task="detection").lens_steps == "range"
        assert make_config(budget).lens_steps == "sigmoid"
    today = make_config("smoke", task="detection")
    older = tmp_path / "older"
    _made_before(older, today, "lens_steps")
    kept = run_dir_settings(older, today)
    assert kept.lens_steps == "sigmoid"
    check_run_dir(older, kept)  # accepted: it resumes as it was made
    with pytest.raises(ValueError, match="lens_steps: 'sigmoid' -> 'range'"):
        check_run_dir(older, today)
    check_run_dir(tmp_path / "new", today)
    assert run_dir_settings(tmp_path / "new", today).lens_steps == "range"
    with pytest.raises(ValueError, match="lens_steps must be one of sigmoid, range"):
        make_config("smoke", lens_steps="adam")


def _made_before(folder, cfg, *settings: str) -> None:
    """A run folder of ``cfg`` as made before ``settings`` existed: its config.json without them."""
    import json

    from optix_e2e.camera_design.config import check_run_dir

    check_run_dir(folder, cfg)
    made = json.loads((folder / "config.json").read_text())
    for k in settings:
        del made[k]
    (folder / "config.json").write_text(json.dumps(made))


def test_a_quick_detection_run_folder_made_at_the_former_lens_rate_resumes_at_it(tmp_path):
    """The detection quick budget's lr_optics went from 3e-2 to 5e-2 (2026-11-28): a run folder
    made at 3e-2 resumes at 3e-2 when the command leaves the rate at the budget's; one made at
    another rate is still held to it, and a new folder gets 5e-2."""
    from optix_e2e.camera_design.config import check_run_dir, make_config, run_dir_settings

    today = make_config("quick", task="detection")
    assert today.lr_optics == 5e-2
    check_run_dir(tmp_path / "a", make_config("quick", task="detection", lr_optics=3e-2))
    kept = run_dir_settings(tmp_path / "a", today)
    assert kept.lr_optics == 3e-2
    check_run_dir(tmp_path / "a", kept)  # accepted: it resumes as it was made
    with pytest.raises(ValueError, match="lr_optics"):
        check_run_dir(tmp_path / "a", today)
    check_run_dir(tmp_path / "b", make_config("quick", task="detection", lr_optics=2e-2))
    assert run_dir_settings(tmp_path / "b", today).lr_optics == 5e-2  # not a former default: refused
    assert run_dir_settings(tmp_path / "c", today).lr_optics == 5e-2
