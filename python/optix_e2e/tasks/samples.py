"""Scenes for the end-to-end tasks: training batches and the fixed held-out set.

A sample is an sRGB scene crop, where it lies on the sensor, and how it is lit:

* Training (``training_batch``): the natural training mix (scenes/natural.py: dead leaves in
  real photos' colours, training photos, textures, text, gradients, edges, the chart) or
  random crops of a user's image folder, at one random position on the sensor per batch
  (top-left on even rows and columns: the CFA phase of the full frame), brightness
  log-uniform in the task's range, under the neutral illuminant the camera is calibrated for
  (``tint`` > 0 draws a per-channel illuminant the ISP is not told of: an ill-posed task,
  off by default; docs/e2e.md, "Illuminant"). Every batch is a
  function of (seed, step) alone, so a resumed run sees the batches it would have seen.
* Evaluation (``heldout_set``): every bundled photo plus procedural scenes from seeds training
  never draws, fixed brightness and neutral light, each at fixed positions on the sensor:
  "frame" is four positions per image drawn uniformly over the frame, one per quadrant
  (stratified), so the mean is the frame's average image quality as training's uniform crop
  positions weigh it; "centre" and "corner" are the two extremes (the image panels show them).
  A design run evaluates all three (``POSITIONS``), the frame its headline
  (camera_design/evaluate.py). The sensor-noise seed is fixed per sample, so every method and
  optics sees the same noise (paired comparisons).

Crops carry a margin of ``margin`` pixels on each side (the PSF half-width): light from just
outside the crop is rendered, then the margin is cut before the sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .. import color, scenes
from ..errors import InputError

HELDOUT_SEED0 = 2_000_000_000  # procedural held-out scenes use seeds from here; training streams are [1, seed, step]
HELDOUT_NOISE0 = 1 << 60  # held-out noise seeds (training noise: SeedSequence([4, seed, step]))
TEST_NOISE0 = 1 << 61  # the test split's noise seeds (docs/test-split.md)
#: a design run's eval_positions: the held-out positions of each image. "frame+centre+corner" (the
#: default, issue 34) puts the frame's four first, so its frame samples (positions
#: and noise seeds) are exactly those of "frame"; "frame" and "centre-corner" stay valid (old runs)
POSITIONS = {
    "frame+centre+corner": ("frame",) * 4 + ("centre", "corner"),
    "frame": ("frame",) * 4,
    "centre-corner": ("centre", "corner"),
}


TRAIN_POSITIONS = ("frame", "radius")  # training_batch's crop positions


@dataclass(frozen=True)
class SensorFrame:
    """The sensor's pixel grid: the optical axis at its centre, the full field at its corners."""

    height: int = 1200
    width: int = 1920

    @property
    def full_field_px(self) -> float:
        return 0.5 * math.hypot(self.height - 1, self.width - 1)

    def offset(self, y0: int, x0: int, size: int) -> tuple[float, float]:
        """Centre of the size x size crop whose top-left pixel is (y0, x0), from the axis."""
        return (y0 + (size - 1) / 2 - (self.height - 1) / 2, x0 + (size - 1) / 2 - (self.width - 1) / 2)

    def corner(self, size: int) -> tuple[int, int]:
        return self.height - size, self.width - size


@dataclass
class Batch:
    scene: torch.Tensor  # [B, 3, S + 2m, S + 2m] linear radiance (1 = calibrated white)
    target: torch.Tensor  # [B, 3, S, S] ideal sRGB rendering of the inner crop
    offset_px: tuple[float, float]
    names: list[str]


def _light(srgb: torch.Tensor, level: np.ndarray, tint: np.ndarray, margin: int) -> tuple[torch.Tensor, torch.Tensor]:
    lin = color.srgb_to_linear(srgb) * torch.as_tensor(level, dtype=srgb.dtype).reshape(-1, 1, 1, 1)
    ideal = color.linear_to_srgb(lin.clamp(0, 1))
    if margin:
        ideal = ideal[..., margin:-margin, margin:-margin]
    return lin * torch.as_tensor(tint, dtype=srgb.dtype).reshape(-1, 3, 1, 1), ideal


def training_scene(size: int, rng: np.random.Generator, corpus=None) -> torch.Tensor:
    """A training scene from the natural mix (scenes/natural.py: dead leaves in the training
    photos' colours, photo crops, textures, text, gradients, edges, the standard chart; with a
    ``corpus`` of photographs, PHOTO_MIX: its native-scale crops the majority); the held-out
    photos and seeds are never drawn."""
    return scenes.natural_scene(size, rng, None, corpus)


def training_batch(
    seed: int,
    step: int,
    batch: int,
    size: int,
    margin: int,
    level_range: tuple[float, float],
    frame: SensorFrame = SensorFrame(),
    folder=None,
    tint: float = 0.0,
    positions: str = "frame",
    corpus=None,
) -> Batch:
    """Batch ``step`` of the training stream ``seed`` (see the module doc). ``positions``: where
    the batch's crop lies, "frame" (uniform over the frame's area) or "radius" (its centre's
    field radius uniform from the axis to the full field, the azimuth uniform, the crop kept
    inside the frame: the centre and the corners weigh as much as the mid-field). ``corpus``: a
    scenes.corpus.PhotoCorpus whose photographs become most of the scenes (PHOTO_MIX)."""
    if positions not in TRAIN_POSITIONS:
        raise InputError(f"training positions must be one of {', '.join(TRAIN_POSITIONS)}, got {positions!r}")
    rng = np.random.default_rng([1, int(seed), int(step)])  # stream tag 1: training batches
    full = size + 2 * margin
    imgs, names = [], []
    for _ in range(batch):
        if folder is not None and rng.random() < 0.5:
            i = int(rng.integers(len(folder)))
            img = folder[i]
            if min(img.shape[-2:]) < full:
                img = scenes.fit_size(img, full)
            imgs.append(scenes.random_crops(img, full, 1, rng)[0])
            names.append(f"folder:{i}")
        else:
            imgs.append(training_scene(full, rng, corpus))
            names.append("procedural")
    if positions == "frame":
        y0 = 2 * int(rng.integers(0, (frame.height - size) // 2 + 1))
        x0 = 2 * int(rng.integers(0, (frame.width - size) // 2 + 1))
    else:
        # the crop centre within a x b of the axis (the crop inside the frame); its distance rho
        # uniform up to the farthest such centre, then the azimuth uniform over the arcs of that
        # circle inside the rectangle (in a quadrant: cos >= ... from a, sin <= ... from b)
        a, b = (frame.width - size) / 2, (frame.height - size) / 2
        rho = rng.uniform(0.0, math.hypot(a, b))
        lo_th = math.acos(min(1.0, a / rho)) if rho > 0 else 0.0
        hi_th = math.asin(min(1.0, b / rho)) if rho > 0 else 0.0
        th = rng.uniform(lo_th, max(lo_th, hi_th))
        sx, sy = rng.choice([-1.0, 1.0], size=2)
        cy = (frame.height - 1) / 2 + sy * rho * math.sin(th)
        cx = (frame.width - 1) / 2 + sx * rho * math.cos(th)
        # even offsets (the Bayer phase), the crop inside the frame
        y0 = 2 * int(np.clip(round((cy - (size - 1) / 2) / 2), 0, (frame.height - size) // 2))
        x0 = 2 * int(np.clip(round((cx - (size - 1) / 2) / 2), 0, (frame.width - size) // 2))
    lo, hi = level_range
    level = np.exp(rng.uniform(math.log(lo), math.log(hi), batch))
    tints = rng.uniform(1 - tint, 1 + tint, (batch, 3))
    lin, ideal = _light(torch.stack(imgs), level, tints, margin)
    return Batch(lin, ideal, frame.offset(y0, x0, size), names)


@dataclass
class HeldoutSample:
    name: str
    position: str  # "centre", "corner" or "frame" (a stratified uniform position)
    scene: torch.Tensor  # [3, S + 2m, S + 2m] linear
    target: torch.Tensor  # [3, S, S] sRGB
    offset_px: tuple[float, float]
    noise_seed: int


def heldout_set(
    size: int,
    margin: int,
    n_procedural: int = 12,
    level: float = 0.7,
    frame: SensorFrame = SensorFrame(),
    photos: list[str] | None = None,
    positions: tuple[str, ...] = ("centre", "corner"),
) -> list[HeldoutSample]:
    """The fixed evaluation set: bundled photos + ``n_procedural`` held-out procedural scenes,
    each at ``positions`` (see the module doc; the j-th "frame" entry of an image lies in
    quadrant j % 4); deterministic."""
    unknown = sorted(set(positions) - {"centre", "corner", "frame"})
    if unknown:
        raise InputError(f"unknown held-out position(s) {unknown}: centre, corner or frame")
    full = size + 2 * margin
    items = [
        (f"photo:{p}", scenes.load_photo(p, full)) for p in (scenes.bundled_photos() if photos is None else photos)
    ]
    items += [
        (f"procedural:{HELDOUT_SEED0 + i}", scenes.mixed_scene(full, HELDOUT_SEED0 + i)) for i in range(n_procedural)
    ]
    out = []
    for k, (name, img) in enumerate(items):
        lin, ideal = _light(img[None], np.array([level]), np.ones((1, 3)), margin)
        for j, pos in enumerate(positions):
            y0, x0 = _sensor_position(pos, 5, k, j, size, frame)  # stream tag 5: held-out positions
            out.append(
                HeldoutSample(name, pos, lin[0], ideal[0], frame.offset(y0, x0, size), HELDOUT_NOISE0 + 1000 * k + j)
            )
    return out


def _sensor_position(pos: str, stream: int, k: int, j: int, size: int, frame: SensorFrame) -> tuple[int, int]:
    """Top-left pixel of image k's j-th evaluation crop: "centre", "corner", or "frame" (uniform
    in quadrant j % 4 of the valid range, on the CFA phase, drawn from stream [stream, k, j])."""
    if pos == "centre":
        return (frame.height - size) // 2 & ~1, (frame.width - size) // 2 & ~1
    if pos == "corner":
        return frame.corner(size)
    rng = np.random.default_rng([stream, k, j])
    qy, qx = divmod(j % 4, 2)
    hy, hx = (frame.height - size) // 4, (frame.width - size) // 4  # half the range, in 2-px steps
    return 2 * (qy * hy + int(rng.integers(0, hy + 1))), 2 * (qx * hx + int(rng.integers(0, hx + 1)))


def photo_test_set(
    corpus,
    size: int,
    margin: int,
    level: float = 0.7,
    frame: SensorFrame = SensorFrame(),
    positions: tuple[str, ...] = POSITIONS["frame+centre+corner"],
) -> list[HeldoutSample]:
    """Samples of photographs at native scale (docs/test-split.md): each photograph of
    ``corpus`` (a scenes.corpus.PhotoCorpus, in its order) at ``positions`` on the sensor
    (frame positions from stream 9), the crop taken where that position lies in the photograph
    as if it filled the frame; noise seeds ``TEST_NOISE0 + 1000 k + j``."""
    unknown = sorted(set(positions) - {"centre", "corner", "frame"})
    if unknown:
        raise InputError(f"unknown position(s) {unknown}: centre, corner or frame")
    full = size + 2 * margin
    out = []
    for k in range(len(corpus)):
        img = corpus[k]
        h, w = img.shape[-2:]
        if h < full or w < full:
            raise InputError(f"{corpus.names[k]}: {h} x {w} pixels, under the {full} x {full} crop at native scale")
        for j, pos in enumerate(positions):
            y0, x0 = _sensor_position(pos, 9, k, j, size, frame)
            py = round(y0 / (frame.height - size) * (h - full))
            px = round(x0 / (frame.width - size) * (w - full))
            crop = img[:, py : py + full, px : px + full]
            lin, ideal = _light(crop[None], np.array([level]), np.ones((1, 3)), margin)
            out.append(
                HeldoutSample(
                    corpus.names[k], pos, lin[0], ideal[0], frame.offset(y0, x0, size), TEST_NOISE0 + 1000 * k + j
                )
            )
    return out
