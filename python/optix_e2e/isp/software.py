"""Software ISP (paper Sec. 3.5 / 4.2): a UNet from RAW straight to the target rendering,
trained end to end (f_NN in Eq. 11). Same body as the proxy (``RawUNet``), no hyperparameters."""

from __future__ import annotations

import torch
from torch import nn

from ..torchfile import build_module, load_plain
from .rawnet import RawUNet


class SoftwareISP(nn.Module):
    def __init__(self, pattern: str = "RGGB", adc_bits: int = 12, base: int = 32, depth: int = 3,
                 pack: bool = True):
        super().__init__()
        self.net = RawUNet(0, pattern, adc_bits, base, depth, pack)

    def forward(self, raw_dn: torch.Tensor) -> torch.Tensor:
        """raw_dn [B, 1, H, W] in digital numbers -> RGB [B, 3, H, W]."""
        return self.net(raw_dn)

    @classmethod
    def load(cls, path, map_location="cpu") -> "SoftwareISP":
        """A checkpoint written by ``optix isp train-software`` (software_isp.pt)."""
        ckpt = load_plain(path, "software ISP checkpoint", map_location=map_location)
        if not isinstance(ckpt, dict) or ckpt.get("format") != "optix-software-isp/1":
            raise ValueError(f"{path}: not an optix software ISP checkpoint (format 'optix-software-isp/1')")
        model = build_module(cls, ckpt.get("config"), ckpt.get("state_dict"), path, "software ISP checkpoint")
        return model.eval()
