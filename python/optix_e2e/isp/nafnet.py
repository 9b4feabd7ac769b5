"""A NAFNet-style restoration network (Chen, Chu, Zhang & Sun, "Simple Baselines for Image
Restoration", ECCV 2022), written for the software ISP's packed RAW input.

Shapes: input [B, C_in, H, W] with H and W multiples of 2**depth, output [B, C_out, H, W].
A U-shaped encoder/decoder (stride-2 conv down, 1x1 conv + pixel shuffle up, additive skips)
of NAF blocks: channel LayerNorm -> 1x1 -> 3x3 depthwise -> SimpleGate (split the channels in
two halves and multiply them) -> 1x1, then a gated 1x1 feed-forward, each branch added back
with a learned per-channel scale that starts at zero (every block starts as the identity).

One change from the paper: its simplified channel attention pools over the whole image, so
a crop's output depends on the crop's size (the paper fixes that at test time with TLC). The
software ISP runs on crops of several sizes and must give a pixel the same output wherever
the crop around it ends, so the attention here pools over a local window (``pool``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError


class LayerNorm2d(nn.Module):
    """LayerNorm over the channels of every pixel of [B, C, H, W]."""

    def __init__(self, c: int, eps: float = 1e-6):
        super().__init__()
        self.weight, self.bias, self.eps = nn.Parameter(torch.ones(c)), nn.Parameter(torch.zeros(c)), eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mu = x.mean(1, keepdim=True)
        var = (x - mu).pow(2).mean(1, keepdim=True)
        return (x - mu) / (var + self.eps).sqrt() * self.weight[:, None, None] + self.bias[:, None, None]


def simple_gate(x: torch.Tensor) -> torch.Tensor:
    a, b = x.chunk(2, dim=1)
    return a * b


class NAFBlock(nn.Module):
    def __init__(self, c: int, pool: int = 7):
        super().__init__()
        self.norm1, self.norm2 = LayerNorm2d(c), LayerNorm2d(c)
        self.conv1 = nn.Conv2d(c, 2 * c, 1)
        self.dw = nn.Conv2d(2 * c, 2 * c, 3, padding=1, groups=2 * c)
        self.attn = nn.Conv2d(c, c, 1)
        self.conv2 = nn.Conv2d(c, c, 1)
        self.ffn1, self.ffn2 = nn.Conv2d(c, 2 * c, 1), nn.Conv2d(c, c, 1)
        self.beta, self.gamma = nn.Parameter(torch.zeros(1, c, 1, 1)), nn.Parameter(torch.zeros(1, c, 1, 1))
        self.pool = pool

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = simple_gate(self.dw(self.conv1(self.norm1(x))))
        # local channel attention: the pooled context of a pool x pool window
        ctx = F.avg_pool2d(y, self.pool, stride=1, padding=self.pool // 2, count_include_pad=False)
        y = self.conv2(y * self.attn(ctx))
        x = x + self.beta * y
        return x + self.gamma * self.ffn2(simple_gate(self.ffn1(self.norm2(x))))


class NAFNet(nn.Module):
    def __init__(
        self,
        in_channels: int,
        out_channels: int = 3,
        width: int = 32,
        depth: int = 3,
        enc_blocks: int = 1,
        mid_blocks: int = 2,
        dec_blocks: int = 1,
    ):
        super().__init__()
        self.depth = depth
        self.intro = nn.Conv2d(in_channels, width, 3, padding=1)
        widths = [width * 2**i for i in range(depth + 1)]
        self.enc = nn.ModuleList(
            [nn.Sequential(*[NAFBlock(widths[i]) for _ in range(enc_blocks)]) for i in range(depth)]
        )
        self.down = nn.ModuleList([nn.Conv2d(widths[i], widths[i + 1], 2, stride=2) for i in range(depth)])
        self.mid = nn.Sequential(*[NAFBlock(widths[depth]) for _ in range(mid_blocks)])
        self.up = nn.ModuleList(
            [
                nn.Sequential(nn.Conv2d(widths[i + 1], widths[i] * 4, 1, bias=False), nn.PixelShuffle(2))
                for i in reversed(range(depth))
            ]
        )
        self.dec = nn.ModuleList(
            [nn.Sequential(*[NAFBlock(widths[i]) for _ in range(dec_blocks)]) for i in reversed(range(depth))]
        )
        self.head = nn.Conv2d(width, out_channels, 3, padding=1)
        self.config = dict(
            in_channels=in_channels,
            out_channels=out_channels,
            width=width,
            depth=depth,
            enc_blocks=enc_blocks,
            mid_blocks=mid_blocks,
            dec_blocks=dec_blocks,
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        step = 2**self.depth
        if x.shape[-1] % step or x.shape[-2] % step:
            raise InputError(f"NAFNet input H and W must be multiples of {step}, got {tuple(x.shape[-2:])}")
        x = self.intro(x)
        skips = []
        for enc, down in zip(self.enc, self.down):
            x = enc(x)
            skips.append(x)
            x = down(x)
        x = self.mid(x)
        for up, dec, skip in zip(self.up, self.dec, reversed(skips)):
            x = dec(up(x) + skip)
        return self.head(x)
