"""Software ISP (paper Sec. 3.5 / 4.2): f_NN of Eq. 11, RAW straight to the rendered picture.

    out = classical(raw) + net( packed [raw, classical(raw), position] )

* ``classical``: the sensor-calibrated pipeline of ``classical.py`` (black level, Malvar
  demosaick, the camera's exact 3x3 to linear scene RGB, sRGB curve): nothing to learn, it
  already gets colour, white balance and exposure right on flat regions.
* ``net``: a restoration network that learns what the classical pipeline cannot do: the
  demosaicking artefacts, the sensor noise, and the lens's blur and vignetting, which vary
  over the field. Its input is packed 2x2 (one packed pixel is one CFA period, as RAW networks
  since Chen et al. 2018 do), its last layer starts at zero (at initialization the ISP is the
  classical pipeline), and with ``position`` it sees where every pixel lies in the frame (two
  channels: the pixel's offset from the optical axis over the full-field radius), so it can
  undo a blur and a shading that depend on the field. Two bodies: the paper's UNet
  (``unet.py``) or NAFNet-style blocks (``nafnet.py``).

A checkpoint of the first version ("optix-software-isp/1": a UNet from RAW alone, no
classical path, no position) still loads.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from ..precision import network_autocast, to_float32
from ..torchfile import build_module, load_plain
from .classical import ClassicalISP
from .nafnet import NAFNet
from .rawnet import RawUNet
from .unet import UNet

FORMATS = ("optix-software-isp/1", "optix-software-isp/2")


def position_channels(
    h: int, w: int, offset_px, full_field_px: float, *, device=None, dtype=torch.float32
) -> torch.Tensor:
    """[B, 2, H, W]: (dy, dx) of every pixel of an H x W crop from the optical axis, over the
    full-field radius; ``offset_px``: the crop centre's (dy, dx) from the axis, one pair for
    the batch or [B, 2]."""
    off = torch.as_tensor(offset_px, dtype=dtype, device=device).reshape(-1, 2)
    y = torch.arange(h, device=device, dtype=dtype) - (h - 1) / 2
    x = torch.arange(w, device=device, dtype=dtype) - (w - 1) / 2
    dy = (y[None, :, None] + off[:, :1, None]).expand(-1, h, w)
    dx = (x[None, None, :] + off[:, 1:, None]).expand(-1, h, w)
    return torch.stack([dy, dx], 1) / float(full_field_px)


class SoftwareISP(nn.Module):
    """RAW [B, 1, H, W] in DN (H, W even) -> sRGB [B, 3, H, W].

    ``arch``: "nafnet" or "unet"; ``width``: channels of the first level; ``depth``: levels;
    ``blocks``: NAF blocks per encoder/decoder level (the middle gets twice as many);
    ``position``: the network sees the field position; ``residual``: the classical pipeline's
    output plus the network's correction (False with ``arch='unet'`` is the first version's
    net, RAW alone to RGB)."""

    #: --precision (optix_e2e.precision): the learned body's autocast dtype, None for float32;
    #: the classical pipeline and the position channels stay float32
    autocast_dtype: "torch.dtype | None" = None

    def __init__(
        self,
        pattern: str = "RGGB",
        adc_bits: int = 12,
        base: int = 32,
        depth: int = 3,
        pack: bool = True,
        *,
        arch: str = "nafnet",
        blocks: int = 1,
        position: bool = True,
        residual: bool = True,
        preset: str = "imx249",
    ):
        super().__init__()
        if arch not in ("nafnet", "unet"):
            raise InputError(f"arch must be nafnet or unet, got {arch!r}")
        if not residual and (arch != "unet" or position):
            raise InputError("residual=False is the first version's network: arch='unet', position=False")
        self.arch, self.position, self.residual, self.blocks = arch, bool(position), bool(residual), int(blocks)
        self.pattern, self.adc_bits, self.base_width, self.depth, self.pack = pattern, adc_bits, base, depth, pack
        if not residual:
            self.net = RawUNet(0, pattern, adc_bits, base, depth, pack)
            return
        if not pack:
            raise InputError("the software ISP packs its RAW input 2x2 (pack=True)")
        self.classical = ClassicalISP(preset)
        c_in = 4 * (1 + 3 + (2 if position else 0))  # packed: RAW, the classical RGB, the position
        if arch == "unet":
            self.body = UNet(c_in, 12, base=base, depth=depth)
        else:
            self.body = NAFNet(
                c_in, 12, width=base, depth=depth, enc_blocks=blocks, mid_blocks=2 * blocks, dec_blocks=blocks
            )
        head = self.body.head
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)

    def config(self) -> dict:
        return dict(
            pattern=self.pattern,
            adc_bits=self.adc_bits,
            base=self.base_width,
            depth=self.depth,
            pack=self.pack,
            arch=self.arch,
            blocks=self.blocks,
            position=self.position,
            residual=self.residual,
        )

    def calibrate(self, preset) -> "SoftwareISP":
        """Set the classical path from the camera's sensor preset (its black level, gain and
        radiance calibration); the first version's network has none."""
        if self.residual:
            self.classical.calibrate(preset)
        return self

    def forward(self, raw_dn: torch.Tensor, offset_px=(0.0, 0.0), full_field_px: float | None = None) -> torch.Tensor:
        """``offset_px``: the crop centre's (dy, dx) from the optical axis in pixels;
        ``full_field_px``: the frame's half diagonal (needed with ``position``)."""
        if not self.residual:
            return self.net(raw_dn)
        if raw_dn.dim() != 4 or raw_dn.shape[1] != 1:
            raise InputError(f"expected a RAW batch [B, 1, H, W], got {tuple(raw_dn.shape)}")
        b, _, h, w = raw_dn.shape
        if h % 2 or w % 2:
            raise InputError(f"the software ISP needs whole CFA periods (even H and W), got {h}x{w}")
        base = self.classical(raw_dn)
        feats = [raw_dn / (2.0**self.adc_bits - 1), base]
        if self.position:
            if not full_field_px:
                raise InputError("this software ISP sees the field position: give full_field_px")
            pos = position_channels(h, w, offset_px, full_field_px, device=raw_dn.device, dtype=raw_dn.dtype)
            feats.append(pos.expand(b, -1, -1, -1))  # one offset for the batch, or one per sample
        x = torch.cat(feats, 1)
        step = 2 ** (self.depth + 1)
        ph, pw = (-h) % step, (-w) % step
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="reflect")  # even pads keep the CFA phase
        with network_autocast(x, self.autocast_dtype):  # --precision: the learned body only
            body = to_float32(self.body(F.pixel_unshuffle(x, 2)))
        out = F.pixel_shuffle(body, 2)[..., :h, :w]
        return base + out

    @classmethod
    def load(cls, path, map_location="cpu") -> "SoftwareISP":
        """A checkpoint written by ``optix isp train-software`` (software_isp.pt)."""
        ckpt = load_plain(path, "software ISP checkpoint", map_location=map_location)
        if not isinstance(ckpt, dict) or ckpt.get("format") not in FORMATS:
            raise InputError(f"{path}: not an optix software ISP checkpoint (format {' or '.join(FORMATS)})")
        config = ckpt.get("config")
        if ckpt["format"] == FORMATS[0] and isinstance(config, dict):
            config = {**config, "arch": "unet", "position": False, "residual": False}
        model = build_module(cls, config, ckpt.get("state_dict"), path, "software ISP checkpoint")
        model.meta = ckpt.get("meta") if isinstance(ckpt.get("meta"), dict) else {}
        return model.eval()
