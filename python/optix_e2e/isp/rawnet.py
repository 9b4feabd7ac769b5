"""RAW -> RGB network body shared by the ISP proxy and the software ISP.

RAW [B, 1, H, W] (digital numbers) -> / white level -> fixed bilinear demosaick + the CFA
sampling masks (6 channels; paper Sec. 4.2) -> optionally packed 2x2 -> 4x channels (pixel
unshuffle, as RAW networks since Chen et al. 2018 do: the same receptive field for a quarter
of the cost; one packed pixel is one CFA period) -> concat constant conditioning channels ->
UNet -> unpack -> [B, 3, H, W].
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from ..precision import network_autocast, to_float32
from .demosaick import BilinearDemosaick
from .unet import UNet, pad_to_multiple


class RawUNet(nn.Module):
    #: --precision (optix_e2e.precision): the UNet's autocast dtype, None for float32; the fixed
    #: demosaick in front of it stays float32
    autocast_dtype: "torch.dtype | None" = None

    def __init__(
        self,
        n_cond: int = 0,
        pattern: str = "RGGB",
        adc_bits: int = 12,
        base: int = 32,
        depth: int = 3,
        pack: bool = True,
    ):
        super().__init__()
        self.n_cond, self.pattern, self.adc_bits, self.pack = n_cond, pattern, adc_bits, pack
        self.demosaick = BilinearDemosaick(pattern, with_masks=True)
        f = 4 if pack else 1
        self.unet = UNet(6 * f + n_cond, 3 * f, base=base, depth=depth)

    def config(self) -> dict:
        return dict(
            pattern=self.pattern,
            adc_bits=self.adc_bits,
            base=self.unet.config["base"],
            depth=self.unet.config["depth"],
            pack=self.pack,
        )

    def forward(self, raw_dn: torch.Tensor, cond: torch.Tensor | None = None) -> torch.Tensor:
        """raw_dn [B, 1, H, W]; cond [B, n_cond] constants broadcast over the image."""
        if raw_dn.dim() != 4 or raw_dn.shape[1] != 1:
            raise InputError(f"expected a RAW batch [B, 1, H, W], got {tuple(raw_dn.shape)}")
        x, (h, w) = pad_to_multiple(raw_dn / (2.0**self.adc_bits - 1), 2 ** (self.unet.depth + self.pack))
        feats = self.demosaick(x)
        if self.pack:
            feats = F.pixel_unshuffle(feats, 2)
        if self.n_cond:
            feats = torch.cat([feats, cond[:, :, None, None].to(feats).expand(-1, -1, *feats.shape[-2:])], 1)
        with network_autocast(feats, self.autocast_dtype):  # --precision: the UNet only
            out = to_float32(self.unet(feats))
        if self.pack:
            out = F.pixel_shuffle(out, 2)
        return out[..., :h, :w]
