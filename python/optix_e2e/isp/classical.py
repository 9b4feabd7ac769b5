"""A classical RAW -> sRGB pipeline fixed by the sensor's calibration, differentiable.

    raw DN -> minus black level -> demosaick (Malvar-He-Cutler 2004, or bilinear)
           -> camera RGB to linear scene RGB (3x3) -> clip -> sRGB curve

The 3x3 matrix inverts the sensor model's noise-free response (sensor/emva.py) at the
preset's exposure, gain and radiance scale, fitted on the ColorChecker and the grey axis, so
a flat grey comes out as the scene's grey and a flat colour close to it: white balance,
colour correction and exposure in one calibrated step, as a camera's ISP applies them from
its calibration data. What it cannot
do (demosaicking artefacts, noise, the lens's blur and vignetting) is the learned part of the
software ISP (``software.py``), which adds its correction to this pipeline's output.

Low light (exposure / 100, gain x 100) gives the same DN per unit radiance, so the same matrix.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .. import color
from ..errors import InputError
from ..sensor import get_preset
from ..sensor.cfa import bayer_masks, check_pattern
from ..sensor.emva import expected_electrons
from .demosaick import bilinear_demosaick

# Malvar, He & Cutler (ICASSP 2004), Fig. 2 filters (x 1/8), the same as reference.py's.
_G_AT_RB = [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]]
_C_AT_G_ROW = [[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, 0.5, 0, 0]]
_C_AT_OPP = [[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0], [0, 0, -1.5, 0, 0]]
_MALVAR = torch.tensor([_G_AT_RB, _C_AT_G_ROW, np.array(_C_AT_G_ROW).T.tolist(), _C_AT_OPP]) / 8


def malvar_demosaick(cfa: torch.Tensor, pattern: str = "RGGB") -> torch.Tensor:
    """CFA image [B, 1, H, W] -> RGB [B, 3, H, W] by Malvar-He-Cutler's gradient-corrected
    linear filters (reflect padding keeps the CFA phase). Differentiable."""
    if cfa.dim() != 4 or cfa.shape[1] != 1:
        raise InputError(f"malvar_demosaick expects [B, 1, H, W], got {tuple(cfa.shape)}")
    h, w = cfa.shape[-2:]
    m = bayer_masks(pattern, h, w, device=cfa.device, dtype=cfa.dtype)  # [3, H, W]
    est = F.conv2d(F.pad(cfa, (2, 2, 2, 2), mode="reflect"), _MALVAR.to(cfa)[:, None])  # [B, 4, H, W]
    g_rb, c_row, c_col, c_opp = est.unbind(1)
    x = cfa[:, 0]
    out = [None, torch.where(m[1] > 0, x, g_rb), None]
    for c in (0, 2):
        in_row = (m[c].sum(1, keepdim=True) > 0).expand(h, w)  # rows that hold this colour
        at_g = torch.where(in_row, c_row, c_col)
        out[c] = torch.where(m[c] > 0, x, torch.where(m[1] > 0, at_g, c_opp))
    return torch.stack(out, 1)


def camera_response(linear_rgb: torch.Tensor, preset="imx249") -> torch.Tensor:
    """Noise-free DN above black of the R, G and B pixels to flat patches [N, 3] -> [N, 3]."""
    p = get_preset(preset)
    e = expected_electrons(linear_rgb.double()[:, :, None, None], p)[:, :, 0, 0]
    return e * p.gain_dn_per_e


def to_linear_matrix(preset="imx249") -> np.ndarray:
    """[3, 3]: camera RGB (DN above black) -> linear scene RGB, the least-squares inverse of
    the sensor's response over the 24 ColorChecker patches and the grey axis (weighted 10x:
    neutrals come out neutral). The sensor model is linear per colour only where its
    spectral interpolation stays positive, so no 3x3 inverts it everywhere: saturated
    colours keep a residual error the learned correction takes out."""
    cc = color.colorchecker_srgb(linear=True).double()
    greys = torch.linspace(0.02, 0.9, 12, dtype=torch.float64)[:, None].expand(-1, 3)
    lin = torch.cat([cc, greys])
    w = torch.cat([torch.ones(len(cc)), torch.full((len(greys),), 10.0)]).double()[:, None]
    cam = camera_response(lin, preset)
    m = torch.linalg.lstsq(cam * w, lin * w).solution  # lin ~ cam @ m
    return m.T.numpy()


def classical_isp(
    raw_dn: torch.Tensor,
    to_linear: torch.Tensor,
    black_level_dn: float,
    pattern: str = "RGGB",
    demosaick: str = "malvar",
) -> torch.Tensor:
    """RAW [B, 1, H, W] in DN -> sRGB [B, 3, H, W]; ``to_linear`` [3, 3] camera RGB (DN above
    black) -> linear scene RGB (:func:`to_linear_matrix`)."""
    x = raw_dn - black_level_dn
    cam = malvar_demosaick(x, pattern) if demosaick == "malvar" else bilinear_demosaick(x, pattern)
    lin = torch.einsum("ij,bjhw->bihw", to_linear.to(cam), cam)
    return color.linear_to_srgb(lin.clamp(0, 1))


class ClassicalISP(nn.Module):
    """nn.Module twin of :func:`classical_isp`, calibrated for a sensor preset (name or
    SensorPreset; the camera's own, with its f-number calibration). Nothing to learn."""

    def __init__(self, preset="imx249", demosaick: str = "malvar"):
        super().__init__()
        if demosaick not in ("malvar", "bilinear"):
            raise InputError(f"demosaick must be malvar or bilinear, got {demosaick!r}")
        self.demosaick = demosaick
        self.pattern = check_pattern("RGGB")
        self.register_buffer("to_linear", torch.zeros(3, 3))
        self.register_buffer("black_level_dn", torch.zeros(()))
        self.calibrate(preset)

    def calibrate(self, preset) -> "ClassicalISP":
        """Set the matrix, black level and CFA pattern from ``preset``."""
        p = get_preset(preset)
        self.pattern = check_pattern(p.cfa)
        if self.to_linear.is_meta:  # built on the meta device to check a checkpoint's shapes
            return self
        self.to_linear.copy_(torch.as_tensor(to_linear_matrix(p), dtype=torch.float32))
        self.black_level_dn.fill_(float(p.black_level_dn))
        return self

    def forward(self, raw_dn: torch.Tensor) -> torch.Tensor:
        return classical_isp(raw_dn, self.to_linear, self.black_level_dn, self.pattern, self.demosaick)
