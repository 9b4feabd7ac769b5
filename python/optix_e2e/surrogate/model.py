"""The optics meta-network (paper Sec. 4.1, Fig. 5, Eq. 6).

Normalized lens parameters and the field position go through an MLP encoder; the MLP's
features give (a) the RGB vignetting (relative illumination) directly, through a linear
head, and (b) a convolutional decoder's input, which upsamples to an RGB PSF. A softmax over
each channel's pixels makes that PSF energy-preserving (unit sum per channel, as the dataset's
PSFs are); the surrogate's PSF for rendering is it scaled channel-wise by the vignetting.

Shapes: params [B, P] (normalized: (value - mean) / std over the training designs), field
[B] (field angle / full field, in [0, 1]) -> psf [B, C, S, S] (unit sum per channel),
vignetting [B, C].
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from ..errors import InputError


@dataclass(frozen=True)
class SurrogateConfig:
    """Size of the network. ``psf_size`` S is the output window (pixels); the decoder starts
    at ceil(S / 2**n_up) pixels with ``base_channels`` channels, doubles its size ``n_up``
    times (halving the channels, at least 16) and crops the centre S x S."""

    n_params: int
    channels: int = 3
    psf_size: int = 21
    hidden: int = 256
    depth: int = 4
    base_channels: int = 64
    n_up: int = 2

    def check(self) -> None:
        for name in ("n_params", "channels", "psf_size", "hidden", "depth", "base_channels"):
            if getattr(self, name) < 1:
                raise InputError(f"surrogate config: {name} must be >= 1, got {getattr(self, name)}")
        if self.n_up < 0:
            raise InputError(f"surrogate config: n_up must be >= 0, got {self.n_up}")

    @property
    def start_size(self) -> int:
        return math.ceil(self.psf_size / 2**self.n_up)

    def to_json(self) -> dict:
        return asdict(self)


def _up_block(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Upsample(scale_factor=2, mode="nearest"),
        nn.Conv2d(c_in, c_out, 3, padding=1),
        nn.SiLU(),
        nn.Conv2d(c_out, c_out, 3, padding=1),
        nn.SiLU(),
    )


class SurrogateNet(nn.Module):
    """MLP encoder -> (vignetting head, conv decoder -> per-channel softmax PSF)."""

    def __init__(self, cfg: SurrogateConfig):
        super().__init__()
        cfg.check()
        self.cfg = cfg
        layers, width = [], cfg.n_params + 1
        for _ in range(cfg.depth):
            layers += [nn.Linear(width, cfg.hidden), nn.SiLU()]
            width = cfg.hidden
        self.encoder = nn.Sequential(*layers)
        self.vignetting_head = nn.Linear(cfg.hidden, cfg.channels)
        s0, c = cfg.start_size, cfg.base_channels
        self.to_grid = nn.Linear(cfg.hidden, c * s0 * s0)
        blocks = []
        for _ in range(cfg.n_up):
            blocks.append(_up_block(c, max(c // 2, 16)))
            c = max(c // 2, 16)
        self.decoder = nn.Sequential(*blocks, nn.Conv2d(c, cfg.channels, 3, padding=1))

    def forward(self, params: torch.Tensor, field: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """params [B, P] normalized, field [B] in [0, 1] -> (psf [B, C, S, S] unit sum, vignetting [B, C])."""
        cfg = self.cfg
        if params.dim() != 2 or params.shape[1] != cfg.n_params:
            raise InputError(f"params must be [B, {cfg.n_params}], got {list(params.shape)}")
        field = field.reshape(-1, 1).to(params)
        if field.shape[0] != params.shape[0]:
            raise InputError(f"field has {field.shape[0]} entries for {params.shape[0]} parameter rows")
        h = self.encoder(torch.cat([params, 2 * field - 1], dim=1))  # field centred like the params
        vignetting = self.vignetting_head(h)
        s0 = cfg.start_size
        x = self.decoder(self.to_grid(h).reshape(-1, cfg.base_channels, s0, s0))
        top = (x.shape[-1] - cfg.psf_size) // 2
        logits = x[..., top : top + cfg.psf_size, top : top + cfg.psf_size]
        b, c, s, _ = logits.shape
        psf = torch.softmax(logits.reshape(b, c, s * s), dim=-1).reshape(b, c, s, s)
        return psf, vignetting
