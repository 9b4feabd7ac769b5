"""The image-quality tasks of paper Sec. 6.1 (Tables 2-3): what the camera is for, as a loss.

* ``iq-software``: the software ISP f_NN (a UNet) renders the picture; L = L1 + LPIPS.
* ``iq-hardware``: the hardware ISP, its proxy in the loop with its hyperparameters learned;
  L = L1 + 3 LPIPS; evaluated through the true reference ISP at the learned hyperparameters.
* ``low-light``: as iq-software at exposure / 100 and gain x 100 (the same mean DN from 100x
  fewer photons: the shot noise the network must remove grows 10x).

The target of every task is the ideal rendering of the scene (what a perfect camera would
output at the captured brightness, sRGB); LPIPS is AlexNet v0.1 (metrics/lpips.py), the
paper's perceptual loss.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..metrics.lpips import LPIPS
from .plugin import TaskPlugin


@dataclass(frozen=True)
class ImageQualityTask:
    name: str
    isp: str  # "software" (f_NN) or "hardware" (proxy in the loop, reference in evaluation)
    lpips_weight: float  # L = L1 + lpips_weight * LPIPS
    exposure_factor: float = 1.0  # x the sensor preset's exposure (5 ms for the IMX249)
    gain_factor: float = 1.0  # x its gain
    level_min: float = 0.35  # scene white in units of the calibrated white (log-uniform in training)
    level_max: float = 1.0
    description: str = ""


_HOOKS = "optix_e2e.camera_design.image_quality:ImageQualityHooks"  # one set of hooks for the three

IQ_SOFTWARE = TaskPlugin(
    ImageQualityTask(
        "iq-software", "software", 1.0, description="image quality, software ISP (paper Table 2, rows 1-2)"
    ),
    _HOOKS,
    help="image quality behind the software ISP (a UNet): L1 + LPIPS (paper Table 2)",
)
IQ_HARDWARE = TaskPlugin(
    ImageQualityTask(
        "iq-hardware", "hardware", 3.0, description="image quality, hardware ISP through its proxy (Table 2, rows 3-4)"
    ),
    _HOOKS,
    help="image quality behind the hardware ISP, its proxy in the loop: L1 + 3 LPIPS (paper Table 2)",
)
LOW_LIGHT = TaskPlugin(
    ImageQualityTask(
        "low-light",
        "software",
        1.0,
        exposure_factor=0.01,
        gain_factor=100.0,
        description="low-light imaging: exposure / 100, gain x 100 (Table 3)",
    ),
    _HOOKS,
    help="low-light imaging: the software ISP at exposure / 100, gain x 100 (paper Table 3)",
)


def task_loss(
    output: torch.Tensor, target: torch.Tensor, lpips_module: nn.Module, lpips_weight: float, crop: int = 0
) -> tuple[torch.Tensor, dict]:
    """L1 + w LPIPS of sRGB images [B, 3, H, W] (batch means); ``crop`` border pixels dropped.
    Returns (loss, {"l1", "lpips"})."""
    if crop:
        output, target = output[..., crop:-crop, crop:-crop], target[..., crop:-crop, crop:-crop]
    l1 = (output - target).abs().mean()
    lp = (
        lpips_module(output, target).mean()
        if lpips_weight
        else torch.zeros((), dtype=output.dtype, device=output.device)
    )
    return l1 + lpips_weight * lp, {"l1": float(l1.detach()), "lpips": float(lp.detach())}


class TaskLoss(nn.Module):
    """Module twin of :func:`task_loss` for one task: forward(output, target) -> (loss, parts)."""

    def __init__(self, task: ImageQualityTask, crop: int = 0):
        super().__init__()
        self.weight, self.crop = float(task.lpips_weight), int(crop)
        self.lpips = LPIPS()

    def forward(self, output: torch.Tensor, target: torch.Tensor):
        return task_loss(output, target, self.lpips, self.weight, self.crop)
