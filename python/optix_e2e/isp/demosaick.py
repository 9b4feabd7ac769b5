"""Fixed bilinear demosaicking layer in torch (the proxy's first layer, paper Sec. 4.2).

Not trainable: it interpolates each colour from its own CFA sites with the classic bilinear
kernels, so the network after it sees an RGB image for any of the four Bayer phases.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from ..sensor.cfa import bayer_masks, check_pattern

_RB = torch.tensor([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 4
_G = torch.tensor([[0.0, 1.0, 0.0], [1.0, 4.0, 1.0], [0.0, 1.0, 0.0]]) / 4


def bilinear_demosaick(cfa: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """CFA image [B, 1, H, W] -> RGB [B, 3, H, W]. Reflect padding keeps the CFA phase."""
    if cfa.dim() != 4 or cfa.shape[1] != 1:
        raise InputError(f"bilinear_demosaick expects [B, 1, H, W], got {tuple(cfa.shape)}")
    m = bayer_masks(pattern, cfa.shape[-2], cfa.shape[-1], device=cfa.device, dtype=cfa.dtype)
    k = torch.stack([_RB, _G, _RB]).unsqueeze(1).to(cfa)  # [3, 1, 3, 3]
    x = F.pad(cfa * m.unsqueeze(0), (1, 1, 1, 1), mode="reflect")
    return F.conv2d(x, k, groups=3)


class BilinearDemosaick(nn.Module):
    """nn.Module twin of :func:`bilinear_demosaick`; ``with_masks`` also returns the CFA's
    sampling masks as 3 extra channels, so later layers know which values were measured."""

    def __init__(self, pattern: str = "RGGB", with_masks: bool = False):
        super().__init__()
        self.pattern = check_pattern(pattern)
        self.with_masks = with_masks

    def forward(self, cfa: torch.Tensor) -> torch.Tensor:
        rgb = bilinear_demosaick(cfa, self.pattern)
        if not self.with_masks:
            return rgb
        m = bayer_masks(self.pattern, cfa.shape[-2], cfa.shape[-1], device=cfa.device, dtype=cfa.dtype)
        return torch.cat([rgb, m.unsqueeze(0).expand(cfa.shape[0], -1, -1, -1)], dim=1)
