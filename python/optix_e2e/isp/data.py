"""Training and evaluation data for the ISP networks: scene -> sensor RAW -> reference ISP.

A capture draws a random illumination level (log-uniform, so the RAW spans dim to nearly
saturated and its shot noise varies) and a random illuminant tint (so white balance has work
to do), simulates the sensor (noise on, real rounding in the ADC), and runs the reference ISP
under random hyperparameters. Scenes for training are procedural (dead leaves with uniformly drawn colours, slanted edges,
colour charts); the bundled photos are kept for evaluation only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from .. import color, scenes
from ..errors import InputError
from ..sensor import get_preset, simulate_raw
from . import params as hp
from . import reference


@dataclass(frozen=True)
class Capture:
    """How scenes are lit and captured."""

    preset: str = "imx249"
    level_min: float = 0.12  # scene white in units of the sensor's default white level
    level_max: float = 1.0
    tint: float = 0.25  # per-channel illuminant gain in [1 - tint, 1 + tint]


def reference_isp(capture: Capture = Capture()) -> reference.ReferenceISP:
    """The reference ISP set up for the capture's sensor (its CFA pattern and ADC depth)."""
    preset = get_preset(capture.preset)
    return reference.ReferenceISP(preset.cfa, preset.adc_bits)


def training_scene(size: int, rng: np.random.Generator) -> torch.Tensor:
    """One procedural sRGB scene [3, size, size]: mostly dead leaves, some edges and charts."""
    u = rng.random()
    seed = int(rng.integers(2**31))
    if u < 0.7:
        return scenes.dead_leaves(size, seed, colors="uniform")
    if u < 0.85:
        return scenes.slanted_edge(size, angle_deg=float(rng.uniform(-45, 45)), seed=seed)
    return scenes.color_chart(size, seed=seed)


def light(scene_srgb: torch.Tensor, rng: np.random.Generator, capture: Capture) -> tuple[torch.Tensor, torch.Tensor]:
    """sRGB scene [B, 3, H, W] -> (linear radiance seen by the sensor, ideal rendering [B, 3, H, W]).

    The ideal rendering is what a perfect camera would output: the scene at the captured
    brightness, neutral illuminant, sRGB-encoded. It is the target of image-quality losses."""
    b = scene_srgb.shape[0]
    level = np.exp(rng.uniform(np.log(capture.level_min), np.log(capture.level_max), size=(b, 1, 1, 1)))
    tint = rng.uniform(1 - capture.tint, 1 + capture.tint, size=(b, 3, 1, 1))
    lin = color.srgb_to_linear(scene_srgb) * torch.as_tensor(level, dtype=scene_srgb.dtype)
    ideal = color.linear_to_srgb(lin.clamp(0, 1))
    return lin * torch.as_tensor(tint, dtype=scene_srgb.dtype), ideal


def capture_raw(
    scene_srgb: torch.Tensor,
    rng: np.random.Generator,
    capture: Capture = Capture(),
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """sRGB scenes [B, 3, H, W] -> (RAW [B, 1, H, W] in DN, ideal rendering [B, 3, H, W])."""
    lin, ideal = light(scene_srgb, rng, capture)
    with torch.no_grad():
        raw = simulate_raw(lin, get_preset(capture.preset), quantize="round", generator=generator)
    return raw, ideal


@dataclass
class Pool:
    raw: torch.Tensor  # [N, 1, S, S] float32 DN
    params_unit: torch.Tensor  # [N, n] in [0, 1]
    target: torch.Tensor  # [N, 3, S, S] uint8 reference-ISP output
    ideal: torch.Tensor  # [N, 3, S, S] uint8 ideal rendering

    def batch(self, idx) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.raw[idx], self.params_unit[idx], self.target[idx].float() / 255


def make_pool(
    n: int,
    size: int,
    seed: int,
    capture: Capture = Capture(),
    *,
    scene_fn=training_scene,
    progress: bool = True,
    chunk: int = 64,
) -> Pool:
    """n (RAW, hyperparameters, reference output) triples of size x size pixels."""
    if size % 2:
        raise InputError(f"patch size must be even (whole CFA periods), got {size}")
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(seed)
    isp = reference_isp(capture)
    raws, units, targets, ideals = [], [], [], []
    with tqdm(total=n, desc="ISP pairs", unit="img", disable=not progress, leave=False) as bar:
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            scene = torch.stack([scene_fn(size, rng) for _ in range(m)])
            raw, ideal = capture_raw(scene, rng, capture, gen)
            plist = [hp.sample(rng) for _ in range(m)]
            out = isp(raw, plist)
            raws.append(raw.float())
            units.append(hp.unit_tensor(plist))
            targets.append((out * 255).round().to(torch.uint8))
            ideals.append((ideal.clamp(0, 1) * 255).round().to(torch.uint8))
            bar.update(m)
    return Pool(torch.cat(raws), torch.cat(units), torch.cat(targets), torch.cat(ideals))
