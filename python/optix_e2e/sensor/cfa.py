"""Bayer colour filter arrays: the four 2x2 phases, sampling masks and mosaicking.

A CFA pattern is named by its top-left 2x2 block read row by row ("RGGB": R at (0, 0),
G at (0, 1) and (1, 0), B at (1, 1)). Channel order everywhere is (R, G, B).
"""

from __future__ import annotations

import torch

from ..errors import InputError

PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
_CHANNEL = {"R": 0, "G": 1, "B": 2}


def check_pattern(pattern: str) -> str:
    p = pattern.upper()
    if p not in PATTERNS:
        raise InputError(f"unknown CFA pattern {pattern!r}: expected one of {', '.join(PATTERNS)}")
    return p


def bayer_masks(pattern: str, height: int, width: int, *, device=None, dtype=torch.float32) -> torch.Tensor:
    """Sampling masks of a Bayer CFA: [3, H, W], 1 where a pixel measures R, G or B."""
    p = check_pattern(pattern)
    masks = torch.zeros(3, height, width, device=device, dtype=dtype)
    for k, letter in enumerate(p):
        dy, dx = divmod(k, 2)
        masks[_CHANNEL[letter], dy::2, dx::2] = 1
    return masks


def mosaic(rgb: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """RGB image [..., 3, H, W] -> single-channel CFA image [..., 1, H, W] (differentiable)."""
    if rgb.shape[-3] != 3:
        raise InputError(f"mosaic expects 3 colour channels in dim -3, got shape {tuple(rgb.shape)}")
    m = bayer_masks(pattern, rgb.shape[-2], rgb.shape[-1], device=rgb.device, dtype=rgb.dtype)
    return (rgb * m).sum(dim=-3, keepdim=True)
