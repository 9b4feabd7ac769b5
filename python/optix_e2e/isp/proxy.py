"""Learned differentiable proxy of the reference ISP (Tseng et al. 2019; paper Sec. 4.2, Eq. 9).

RAW [B, 1, H, W] (digital numbers) + hyperparameters -> ISP output [B, 3, H, W]: the
``RawUNet`` body (fixed bilinear demosaick layer, then a UNet) with one constant channel per
ISP hyperparameter, range-normalized to [0, 1]. Gradients flow to the RAW and to the
hyperparameters, which is what end-to-end optimization needs; the reference ISP has none.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from ..errors import InputError
from ..io import save_atomic
from ..torchfile import build_module, load_plain
from . import params as hp
from .rawnet import RawUNet

BUNDLED = Path(__file__).with_name("bundled") / "isp_proxy.pt"


class ISPProxy(nn.Module):
    def __init__(self, pattern: str = "RGGB", adc_bits: int = 12, base: int = 32, depth: int = 3, pack: bool = True):
        super().__init__()
        self.n_params = len(hp.SPACE)
        self.net = RawUNet(self.n_params, pattern, adc_bits, base, depth, pack)
        self.meta: dict = {}

    def forward(self, raw_dn: torch.Tensor, params_unit: torch.Tensor) -> torch.Tensor:
        """raw_dn [B, 1, H, W], params_unit [B, n] or [n] in [0, 1] -> [B, 3, H, W]."""
        if params_unit.dim() == 1:
            params_unit = params_unit.unsqueeze(0).expand(raw_dn.shape[0], -1)
        if params_unit.shape != (raw_dn.shape[0], self.n_params):
            raise InputError(
                f"ISP proxy expects hyperparameters [B={raw_dn.shape[0]}, {self.n_params}], "
                f"got {tuple(params_unit.shape)}"
            )
        return self.net(raw_dn, params_unit)

    def render(self, raw_dn: torch.Tensor, params: dict | list[dict]) -> torch.Tensor:
        """Convenience: hyperparameters as dict(s) in physical units."""
        plist = [params] * raw_dn.shape[0] if isinstance(params, dict) else params
        return self(raw_dn, hp.unit_tensor(plist, device=raw_dn.device))

    def save(self, path, **meta) -> None:
        """Weights in float16 (the shipped proxy must stay small) plus everything to rebuild it."""
        state = {k: (v.half() if v.is_floating_point() else v).cpu() for k, v in self.state_dict().items()}
        save_atomic(
            {
                "format": "optix-isp-proxy/1",
                "state_dict": state,
                "config": self.net.config(),
                "space": [(p.name, p.low, p.high) for p in hp.SPACE],
                "meta": {**self.meta, **meta},
            },
            path,
        )

    @classmethod
    def load(cls, path=None, map_location="cpu") -> "ISPProxy":
        path = Path(path) if path is not None else BUNDLED
        if not path.is_file():
            raise FileNotFoundError(f"ISP proxy checkpoint not found: {path}")
        ckpt = load_plain(path, "ISP proxy checkpoint", map_location=map_location)
        if not isinstance(ckpt, dict) or ckpt.get("format") != "optix-isp-proxy/1":
            raise InputError(f"{path}: not an optix ISP proxy checkpoint (format 'optix-isp-proxy/1')")
        try:
            space = [tuple(s) for s in ckpt["space"]]
        except (KeyError, TypeError):
            raise InputError(f"{path}: damaged ISP proxy checkpoint: no hyperparameter space") from None
        expected = [(p.name, p.low, p.high) for p in hp.SPACE]
        if space != expected:
            raise InputError(f"{path}: proxy was trained for hyperparameters {space}, this ISP has {expected}")
        model = build_module(cls, ckpt.get("config"), ckpt.get("state_dict"), path, "ISP proxy checkpoint")
        meta = ckpt.get("meta", {})
        model.meta = dict(meta) if isinstance(meta, dict) else {}
        return model.eval()
