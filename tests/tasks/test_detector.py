"""The detector and its mAP: the mAP implementation against hand-made
cases, the detector learns a tiny set, and its mAP falls as blur and noise grow."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from optix_e2e.color import linear_to_srgb
from optix_e2e.scenes.street import street_scene
from optix_e2e.tasks.detector import detect, make_detector, mean_average_precision

pytestmark = pytest.mark.usefixtures("one_torch_thread")
SIZE = (96, 144)  # 23 objects in 4 scenes; 240 steps reach mAP@0.5 0.96 (128 x 192 needs 300, 2x the time)


def test_map_of_hand_made_detections():
    t = [{"boxes": torch.tensor([[10.0, 10, 50, 50], [60, 60, 80, 80]]), "labels": torch.tensor([1, 2])}]
    exact = [{"boxes": t[0]["boxes"].clone(), "scores": torch.tensor([0.9, 0.8]), "labels": torch.tensor([1, 2])}]
    assert mean_average_precision(exact, t)["map"] == pytest.approx(1.0)
    # the class-2 box at IoU 2/3 (20 x 20 against 20 x 30): counts at 0.5, not from 0.7 on
    loose = [
        {
            "boxes": torch.tensor([[10.0, 10, 50, 50], [60, 60, 80, 90]]),
            "scores": torch.tensor([0.9, 0.8]),
            "labels": torch.tensor([1, 2]),
        }
    ]
    r = mean_average_precision(loose, t)
    assert r["map_50"] == pytest.approx(1.0) and r["map_75"] == pytest.approx(0.5)
    assert r["map"] == pytest.approx((1.0 + 0.4) / 2, abs=1e-6)  # class 2: 4 of 10 IoU thresholds
    wrong = [{**exact[0], "labels": torch.tensor([2, 1])}]
    assert mean_average_precision(wrong, t)["map"] == 0.0 and r["n_objects"] == 2


@pytest.fixture(scope="module")
def overfit():
    torch.manual_seed(0)
    scenes = [street_scene(SIZE, np.random.default_rng([9, i])) for i in range(4)]
    images = torch.stack([linear_to_srgb(s.radiance.clamp(0, 1)) for s in scenes])
    targets = [{"boxes": s.boxes, "labels": s.labels} for s in scenes]
    model = make_detector(image_size=SIZE)
    opt = torch.optim.AdamW(model.parameters(), 2e-3)
    model.train()
    for _ in range(240):
        loss = sum(model(list(images), targets).values())
        opt.zero_grad()
        loss.backward()
        opt.step()
    return model, images, targets


@pytest.mark.slow
def test_the_detector_learns_a_tiny_set(overfit):
    model, images, targets = overfit
    r = mean_average_precision(detect(model, images), targets)
    assert r["n_objects"] >= 20 and r["map_50"] >= 0.9, r


@pytest.mark.slow
def test_map_falls_as_blur_and_noise_grow(overfit):
    from torchvision.transforms.functional import gaussian_blur

    model, images, targets = overfit
    g = torch.Generator().manual_seed(1)
    noise = torch.randn(images.shape, generator=g)
    maps = []
    for sigma, std in ((0.0, 0.0), (1.2, 0.04), (2.5, 0.10)):
        x = gaussian_blur(images, [2 * int(3 * sigma) + 1] * 2, [sigma] * 2) if sigma else images
        maps.append(mean_average_precision(detect(model, (x + std * noise).clamp(0, 1)), targets))
    # both fall by the strong level; at the mild one they may hold within one object's share
    # (23 objects: about 0.04): mAP@0.5 0.962 at both in a CI run (2026-11-27), mAP 0.712 -> 0.733
    # on another machine's arithmetic (2026-11-28), where the strong level gave 0.520
    for m in ("map", "map_50"):
        assert maps[2][m] < min(maps[0][m], maps[1][m]) - 0.1, maps
        assert maps[1][m] <= maps[0][m] + 0.04, maps
    assert maps[2]["map_50"] < maps[0]["map_50"], maps


def test_detector_training_runs_resume_and_evaluate(tmp_path):
    from click.testing import CliRunner

    from optix_e2e.cli import main
    from optix_e2e.scenes.coco import write_street_coco
    from optix_e2e.tasks.detector_train import evaluate_detector, load_detector, train_detector

    write_street_coco(tmp_path / "data", 6, (64, 96), seed=0)
    a = train_detector(tmp_path / "data", tmp_path / "run", steps=3, batch=2, progress=False, log=lambda m: None)
    with open(tmp_path / "run" / "history.csv", "a") as f:  # a row past the checkpoint, as a kill can leave
        f.write("4,9,9,9,9,0.001,0.1\n")
    said = []
    b = train_detector(tmp_path / "data", tmp_path / "run", steps=5, batch=2, progress=False, log=said.append)
    assert a["steps"] == 3 and b["steps"] == 5 and said == ["resuming at step 3 of 5"]
    rows = (tmp_path / "run" / "history.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[1:]] == ["1", "2", "3", "4", "5"]
    model, ck = load_detector(tmp_path / "run")
    assert ck["step"] == 5
    r = evaluate_detector(model, tmp_path / "data")
    assert 0.0 <= r["map"] <= r["map_50"] <= 1.0 and r["n_objects"] > 0 and "dark" in r
    # other settings in the same run directory, a folder that is not a COCO set: one error each
    with pytest.raises(ValueError, match="other settings"):
        train_detector(tmp_path / "data", tmp_path / "run", steps=6, batch=2, seed=1, progress=False)
    r = CliRunner().invoke(main, ["detect", "train", str(tmp_path), "--out", str(tmp_path / "x")])
    assert r.exit_code == 1 and "annotations.json: annotation file not found" in r.output


def test_map_in_the_dark_counts_the_dark_objects_only(tmp_path):
    # a stand-in detector that returns the true boxes: mAP 1 overall and in the dark; the same
    # without its dark detections: 0 in the dark, and the sunlit objects alone keep theirs
    import json

    from optix_e2e.scenes.coco import write_street_coco
    from optix_e2e.tasks.detector_train import evaluate_detector, load_coco_folder

    ann = write_street_coco(tmp_path, 6, (96, 144), seed=2)
    _, targets, ds = load_coco_folder(tmp_path)
    n_dark = sum(a["illumination"] < 0.1 for a in json.loads(ann.read_text())["annotations"])
    assert 0 < n_dark < sum(len(t["labels"]) for t in targets)

    class Oracle(torch.nn.Module):
        def __init__(self, hide_dark):
            super().__init__()
            self.k, self.hide_dark = 0, hide_dark

        def forward(self, images):
            out = []
            for _ in images:
                t, light = targets[self.k], torch.tensor(ds.images[self.k]["illumination"]).reshape(-1)
                keep = light >= 0.1 if self.hide_dark else torch.ones(len(light), dtype=torch.bool)
                out.append(
                    {"boxes": t["boxes"][keep], "labels": t["labels"][keep], "scores": torch.ones(int(keep.sum()))}
                )
                self.k += 1
            return out

    full = evaluate_detector(Oracle(False), tmp_path, batch=4)
    assert full["map"] == pytest.approx(1.0) and full["dark"]["map"] == pytest.approx(1.0)
    assert full["dark"]["n_objects"] == n_dark
    blind = evaluate_detector(Oracle(True), tmp_path, batch=4)
    assert blind["dark"]["map_50"] == 0.0 and 0.0 < blind["map_50"] < 1.0


def test_training_noise_is_the_sensors_photon_and_read_noise(monkeypatch):
    """`optix detect train --noise`: on a uniform linear image the noise has the Poisson-Gaussian
    mean and variance of Eq. 5 at the drawn exposure (here fixed: 0.2 of the calibrated white,
    f/4.4: 5,527 e- for the sunlit white), and a batch is the same for the same (seed, step)."""
    from optix_e2e.tasks import detector_train as dt

    monkeypatch.setattr(dt, "NOISE_LEVELS", (0.2, 0.2))
    monkeypatch.setattr(dt, "NOISE_APERTURE_GAIN", (1.0, 1.0))
    w = dt.NOISE_FULL_WELL_E * dt.NOISE_WHITE * 0.2
    x = 0.01  # 55 e-: photon noise 7.4 e-, read noise 7 e-
    y = dt.sensor_noise(torch.full((3, 256, 256), x, dtype=torch.float64), np.random.default_rng(0))
    assert float(y.mean()) == pytest.approx(x, rel=0.01)
    assert float(y.std()) == pytest.approx(np.sqrt(x * w + dt.NOISE_READ_E**2) / w, rel=0.03)
    # dark images (sRGB up to 40 of 255: linear up to 0.02, a few tens of electrons): noise shows
    images = (torch.rand(3, 3, 24, 36, generator=torch.Generator().manual_seed(0)) * 40).to(torch.uint8)
    targets = [{"boxes": torch.tensor([[2.0, 2, 10, 10]]), "labels": torch.tensor([1])}] * 3
    clean, _ = dt._batch(images, targets, 0, 7, 3)
    noisy, _ = dt._batch(images, targets, 0, 7, 3, noise=1.0)
    again, _ = dt._batch(images, targets, 0, 7, 3, noise=1.0)
    assert all(torch.equal(a, b) for a, b in zip(noisy, again))
    assert all(float((a - b).abs().mean()) > 0.004 for a, b in zip(clean, noisy))
