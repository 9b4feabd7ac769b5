"""The detection task's parts: the photon count follows the lens's
f-number by Eq. 3, a surrogate widened by a parameter starts from its source exactly, the
street batches and held-out scenes, and the paired mAP interval."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from optix_e2e.camera import Camera, FixedOptics, SensorStage, calibrated_preset
from optix_e2e.sensor.emva import expected_electrons
from optix_e2e.sensor.spectral import aperture_factor, aperture_gain
from optix_e2e.tasks import SensorFrame
from optix_e2e.tasks.detection import VALIDATION_STREETS, heldout_streets, street_batch


def test_photon_count_follows_eq3_f_number_form():
    """f/3.2 collects (1 + (2 x 4.4)^2) / (1 + (2 x 3.2)^2) = 78.44 / 41.96 = 1.869 x the photons of
    f/4.4 (Eq. 3's form), not the small-angle (4.4 / 3.2)^2 = 1.891 x; the two differ by 1.1 %,
    more than the 1e-6 asked, so the form is checked, not only the trend."""
    x = torch.rand(1, 3, 8, 8, dtype=torch.float64) * 0.5 + 0.1
    p44, p32 = calibrated_preset("imx249", 4.4), None
    p32 = p44.with_(f_number=3.2)  # same radiance scale: the same scene
    ratio = (expected_electrons(x, p32) / expected_electrons(x, p44)).mean().item()
    assert ratio == pytest.approx(78.44 / 41.96, rel=1e-6)
    assert abs(ratio - (4.4 / 3.2) ** 2) > 0.01
    # the sensor stage scales by the same factor when the lens gives its f-number as a tensor
    stage = SensorStage(p44, noise=False)
    n = torch.tensor(3.2, dtype=torch.float64, requires_grad=True)
    a = stage(x, f_number=n)
    b = stage(x)
    black = p44.black_level_dn
    assert ((a - black) / (b - black)).mean().item() == pytest.approx(78.44 / 41.96, rel=1e-5)
    a.sum().backward()
    assert n.grad is not None and n.grad.item() < 0  # a larger f-number, fewer photons


def test_aperture_gain_gradcheck():
    n = torch.tensor([2.9, 3.2, 4.4, 4.6], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: aperture_gain(v, 4.4), (n,))
    assert aperture_factor(4.4) == pytest.approx(1 / 78.44)


def test_fixed_optics_f_number_reaches_the_sensor():
    psf = torch.zeros(2, 3, 5, 5)
    psf[..., 2, 2] = 1
    vig = torch.ones(2, 3)
    fields = torch.tensor([0.0, 1.0])
    preset = calibrated_preset("imx249", 4.4)
    x = torch.full((1, 3, 12, 12), 0.2)
    outs = {}
    for n in (None, 4.4, 3.2):
        cam = Camera(
            FixedOptics(psf, vig, fields, f_number=n, full_field_px=100.0),
            SensorStage(preset, noise=False),
            torch.nn.Identity(),
        )
        outs[n] = cam(x)[1] - preset.black_level_dn
    assert torch.allclose(outs[None], outs[4.4])
    assert (outs[3.2] / outs[4.4]).mean().item() == pytest.approx(78.44 / 41.96, rel=1e-4)


def test_widened_surrogate_starts_from_its_source_exactly(tmp_path):
    """A space with one more parameter (appended) starts from a network that gives the source's
    PSFs where that parameter is at its mean, whatever the two data sets' normalizations."""
    from optix_e2e.surrogate.checkpoint import OpticsSurrogate
    from optix_e2e.surrogate.model import SurrogateConfig
    from optix_e2e.surrogate.train import _start_from

    def make(n, mean, std):
        cfg = SurrogateConfig(n_params=n, psf_size=9, hidden=16, depth=2, base_channels=16, n_up=1)
        return OpticsSurrogate(
            cfg,
            param_names=["a", "b", "f_number"][:n],
            param_mean=mean,
            param_std=std,
            param_min=[-10] * n,
            param_max=[10] * n,
            fields_deg=[0, 5, 10],
            pitch_um=5.86,
        )

    torch.manual_seed(0)
    src = make(2, [1.0, -2.0], [0.5, 3.0])
    path = tmp_path / "src.pt"
    src.save(path)
    dst = make(3, [1.3, -1.0, 4.0], [0.7, 2.0, 0.5])
    _start_from(dst, str(path))
    v = torch.tensor([[0.4, -3.0], [1.7, 2.5]])
    field = torch.tensor([0.2, 0.9])
    p_src, v_src = src(v, field)
    p_dst, v_dst = dst(torch.cat([v, torch.full((2, 1), 4.0)], 1), field)
    assert torch.allclose(p_src, p_dst, atol=1e-6) and torch.allclose(v_src, v_dst, atol=1e-6)
    # a source whose parameters are not the first of the space's is refused
    other = make(3, [0, 0, 0], [1, 1, 1])
    other.param_names = ["b", "a", "f_number"]
    with pytest.raises(ValueError, match="parameters"):
        _start_from(other, str(path))


def test_street_batches_repeat_and_keep_boxes_in_the_crop():
    frame = SensorFrame()
    a = street_batch(0, 7, 2, (64, 96), 5, (0.1, 0.4), frame)
    b = street_batch(0, 7, 2, (64, 96), 5, (0.1, 0.4), frame)
    c = street_batch(0, 8, 2, (64, 96), 5, (0.1, 0.4), frame)
    assert torch.equal(a.scene, b.scene) and a.offset_px == b.offset_px
    assert not torch.equal(a.scene, c.scene)
    assert a.scene.shape == (2, 3, 74, 106)
    for t in a.targets:
        bx = t["boxes"]
        assert (bx[:, 0] >= 0).all() and (bx[:, 2] <= 96).all() and (bx[:, 1] >= 0).all() and (bx[:, 3] <= 64).all()
    # scenes are dusk-lit: nothing brighter than the level range's top, lamps (2 x) aside
    assert a.scene.max() <= 2 * 0.4 + 1e-6


def test_heldout_streets_cover_the_frame_and_repeat():
    frame = SensorFrame()
    s = heldout_streets(8, (64, 96), 4, (0.1, 0.4), frame)
    again = heldout_streets(8, (64, 96), 4, (0.1, 0.4), frame)
    assert [x.name for x in s] == [x.name for x in again]
    assert all(torch.equal(x.scene, y.scene) and x.offset_px == y.offset_px for x, y in zip(s, again))
    quadrants = {(x.offset_px[0] > 0, x.offset_px[1] > 0) for x in s}
    assert len(quadrants) == 4
    assert len({x.noise_seed for x in s}) == 8
    assert all(0.1 <= x.level <= 0.4 for x in s)


def test_validation_streets_are_other_scenes_than_the_held_out_ones():
    frame = SensorFrame()
    held = heldout_streets(8, (64, 96), 4, (0.1, 0.4), frame)
    val = heldout_streets(8, (64, 96), 4, (0.1, 0.4), frame, start=VALIDATION_STREETS)
    again = heldout_streets(8, (64, 96), 4, (0.1, 0.4), frame, start=VALIDATION_STREETS)
    assert all(torch.equal(x.scene, y.scene) and x.noise_seed == y.noise_seed for x, y in zip(val, again))
    assert not {x.name for x in val} & {x.name for x in held}
    assert not {x.noise_seed for x in val} & {x.noise_seed for x in held}
    assert not any(torch.equal(x.scene, y.scene) for x in val for y in held)
    assert len({(x.offset_px[0] > 0, x.offset_px[1] > 0) for x in val}) == 4  # every quadrant, as held out


def test_paired_map_interval():
    """Identical detections: a difference of exactly 0; an oracle against a blind camera: +1
    with the interval at +1 (every resample has objects)."""
    from optix_e2e.camera_design.detection import paired_map
    from optix_e2e.tasks.detection import DetectionSample

    rng = np.random.default_rng(0)
    samples, oracle, blind = [], [], []
    for i in range(6):
        n = 3
        # apart, so no detection of one object matches another
        xy = torch.tensor([[0.0, 0.0], [20.0, 0.0], [40.0, 0.0]]) + torch.tensor(
            rng.uniform(0, 5, (n, 2)), dtype=torch.float32
        )
        boxes = torch.cat([xy, xy + 10], 1)
        labels = torch.tensor(rng.integers(1, 5, n))
        light = torch.tensor([0.05, 0.5, 0.02])
        samples.append(
            DetectionSample(
                f"s{i}",
                torch.zeros(3, 8, 8),
                {"boxes": boxes, "labels": labels},
                light,
                (0.0, 0.0),
                (64, 64),
                0.0,
                0.2,
                i,
            )
        )
        oracle.append({"boxes": boxes, "scores": torch.ones(n), "labels": labels})
        blind.append(
            {"boxes": torch.zeros(0, 4), "scores": torch.zeros(0), "labels": torch.zeros(0, dtype=torch.int64)}
        )
    same = paired_map(oracle, oracle, samples, 100, 0, 0.1)
    assert same["map_50"]["mean"] == 0 and same["map_50"]["ci95"] == [0.0, 0.0]
    win = paired_map(blind, oracle, samples, 100, 0, 0.1)
    assert win["map_50"]["mean"] == pytest.approx(1.0) and win["map_50"]["ci95"][0] == pytest.approx(1.0)
    assert win["dark"]["map"]["mean"] == pytest.approx(1.0)
    assert math.isclose(win["n_images"], 6)


def test_match_table_equals_torchmetrics_map():
    """The bootstrap's mAP on the whole set is COCO's (torchmetrics, faster-coco-eval backend)
    on noisy detections with misses, false alarms, duplicates and a class without ground truth;
    a resample with an image drawn twice equals that set written out twice."""
    from optix_e2e.metrics.map_bootstrap import MatchTable
    from optix_e2e.tasks.detector import mean_average_precision

    rng = np.random.default_rng(3)
    preds, targets = [], []
    for _ in range(12):
        n = int(rng.integers(0, 7))
        xy = torch.tensor(rng.uniform(0, 200, (n, 2)), dtype=torch.float32)
        wh = torch.tensor(rng.uniform(6, 60, (n, 2)), dtype=torch.float32)
        gt = torch.cat([xy, xy + wh], 1)
        labels = torch.tensor(rng.integers(1, 4, n), dtype=torch.int64)
        keep = torch.tensor(rng.random(n) < 0.8, dtype=torch.bool)
        det = gt[keep] + torch.tensor(rng.normal(0, 4, (int(keep.sum()), 4)), dtype=torch.float32)
        det = torch.cat([torch.minimum(det[:, :2], det[:, 2:] - 1), torch.maximum(det[:, 2:], det[:, :2] + 1)], 1)
        dl = labels[keep].clone()
        k = int(rng.integers(0, 4))  # false alarms, some of class 4 which has no ground truth
        fa = torch.tensor(rng.uniform(0, 200, (k, 2)), dtype=torch.float32)
        det = torch.cat([det, torch.cat([fa, fa + 20], 1), det[:1] + 2])  # and a duplicate
        dl = torch.cat([dl, torch.tensor(rng.integers(1, 5, k), dtype=torch.int64), dl[:1]])
        preds.append({"boxes": det, "scores": torch.tensor(rng.random(len(det)), dtype=torch.float32), "labels": dl})
        targets.append({"boxes": gt, "labels": labels})
    # COCO's own evaluation (faster-coco-eval's COCOeval, on the boxes as COCO JSON)
    from faster_coco_eval import COCO, COCOeval_faster

    gt = {"images": [{"id": i} for i in range(12)], "categories": [{"id": c} for c in (1, 2, 3, 4)], "annotations": []}
    dts = []
    for i, (p, t) in enumerate(zip(preds, targets)):
        for (x0, y0, x1, y1), lab in zip(t["boxes"].tolist(), t["labels"].tolist()):
            gt["annotations"].append(
                {
                    "id": len(gt["annotations"]) + 1,
                    "image_id": i,
                    "category_id": lab,
                    "bbox": [x0, y0, x1 - x0, y1 - y0],
                    "area": (x1 - x0) * (y1 - y0),
                    "iscrowd": 0,
                }
            )
        for (x0, y0, x1, y1), lab, sc in zip(p["boxes"].tolist(), p["labels"].tolist(), p["scores"].tolist()):
            dts.append({"image_id": i, "category_id": lab, "bbox": [x0, y0, x1 - x0, y1 - y0], "score": sc})
    coco = COCO(gt)
    ev = COCOeval_faster(coco, coco.loadRes(dts), "bbox", print_function=lambda *a: None)
    ev.evaluate(), ev.accumulate(), ev.summarize()
    got = MatchTable(preds, targets).scores()
    assert got["map"] == pytest.approx(ev.stats[0], abs=1e-6) and got["map_50"] == pytest.approx(ev.stats[1], abs=1e-6)
    # torchmetrics' wrapper (the per-camera figures) agrees to its own conversion of the boxes
    ref = mean_average_precision(preds, targets)
    assert got["map"] == pytest.approx(ref["map"], abs=2e-3) and got["map_50"] == pytest.approx(ref["map_50"], abs=2e-3)
    w = np.ones(12)
    w[[2, 5]] = [2, 0]
    sel = [0, 1, 2, 2, 3, 4, 6, 7, 8, 9, 10, 11]
    ref_w = mean_average_precision([preds[i] for i in sel], [targets[i] for i in sel])
    got_w = MatchTable(preds, targets).scores(w)
    assert got_w["map_50"] == pytest.approx(ref_w["map_50"], abs=0.01) and got_w["map"] == pytest.approx(
        ref_w["map"], abs=0.01
    )


def _f_number_after(
    lr: float, steps: int, scale: float = 1.0, f0: float = 4.4, lo: float = 2.8, hi: float = 4.6
) -> float:
    """The f-number Adam reaches on the sigmoid-parameterized aperture (optics/differentiable.py)
    after ``steps`` steps that all ask for a faster lens, each step in u times ``scale``
    (lens_steps = "range"): the farthest a run can take it."""
    s0 = (f0 - lo) / (hi - lo)
    u = torch.tensor([math.log(s0 / (1 - s0))], requires_grad=True)
    opt = torch.optim.Adam([u], lr=lr)
    for _ in range(steps):
        opt.zero_grad()
        (lo + (hi - lo) * torch.sigmoid(u)).sum().backward()
        before = u.detach().clone()
        opt.step()
        with torch.no_grad():
            u.copy_(before + scale * (u - before))
    return float(lo + (hi - lo) * torch.sigmoid(u.detach()))


def test_the_detection_defaults_let_the_aperture_reach_f3_6_at_quick():
    """The detection task's quick and full budgets move the lens in the wide space on exact
    optics, with enough lens steps x learning rate for the aperture to get from the nominal
    f/4.4 to f/3.6 (the issue's quick criterion) and the paper's f/3.2 at full; at the paper's
    lr 1e-2 and Adam's own steps in u the quick budget's 90 lens steps could not (about
    f/4.15). Since 2026-11-28 the aperture's steps are scaled as every other parameter's
    first step is (lens_steps = "range"): 2.53x at f/4.4, 0.89 of its range. The runs on those
    steps moved the aperture at 0.21-0.31 of Adam's full step (benches/aperture_share.py), and
    the quick run at lr 3e-2 stopped at f/3.90: quick's lr is sized on what that run measured."""
    from optix_e2e.camera_design.config import make_config

    scale = 1 / (4 * (1.6 / 1.8) * (0.2 / 1.8))
    for budget, target in (("quick", 3.6), ("full", 3.2)):
        cfg = make_config(budget, task="detection")
        assert (cfg.space, cfg.optics, cfg.lens_steps) == ("paper-triplet-detect-wide", "exact", "range")
        lens_steps = cfg.n_cycles * cfg.steps_optics + cfg.n_finetune
        assert _f_number_after(cfg.lr_optics, lens_steps) <= target, budget
        # the farthest stays about as far when a third of the steps count
        assert _f_number_after(cfg.lr_optics / 3, lens_steps, scale) <= target, budget
    assert _f_number_after(1e-2, 90) == pytest.approx(4.15, abs=0.02)
    assert _f_number_after(3e-2 / 3, 90) > 3.6  # without the scale, a third of the steps fall short
    # what the runs on those steps measured: the quick run at 3e-2 stopped at f/3.90, where
    # this model lands with 0.21 of the lr (a noisy gradient's Adam steps are shorter), and the
    # full budget's seeds at f/3.41-3.82 (0.21 gives f/3.61). Quick's lr reaches the full
    # budget's fastest seed at that share, and f/3.6 at 0.18
    assert _f_number_after(3e-2 * 0.21, 90, scale) == pytest.approx(3.90, abs=0.03)
    assert _f_number_after(1e-2 * 0.21, 350, scale) == pytest.approx(3.61, abs=0.03)
    quick = make_config("quick", task="detection")
    assert _f_number_after(quick.lr_optics * 0.21, 90, scale) <= 3.41
    assert _f_number_after(quick.lr_optics * 0.18, 90, scale) <= 3.6
