"""The reference "hardware" ISP: a fixed-function pipeline in numpy, deliberately not
differentiable (8-bit output, categorical demosaick choice, library filters). It stands in for
the ARM Mali-C71 of the paper (Sec. 3.4); the learned proxy (``proxy.py``) imitates it.

Stages, in hardware order:
  1. black level: x = (raw - black_level) / (white - black_level), negatives clipped
  2. white balance: red and blue CFA sites times wb_red / wb_blue
  3. demosaick: bilinear, or Malvar-He-Cutler 2004 gradient-corrected linear interpolation
  4. denoise: bilateral filter on linear RGB (range sigma = denoise_sigma, spatial 1 px)
  5. colour correction: M = (1 - s) I + s M_sensor, M_sensor fitted to a ColorChecker
  6. tone: y = x^(1/gamma)
  7. sharpen: unsharp mask (amount, radius) on the tone-mapped image
  8. output: clip to [0, 1], quantize to 8 bits
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import convolve
from skimage.filters import unsharp_mask
from skimage.restoration import denoise_bilateral

from ..errors import InputError
from ..sensor.cfa import bayer_masks
from . import params as hp

# Malvar, He & Cutler (ICASSP 2004), Fig. 2 filters (x 1/8).
_G_AT_RB = (
    np.array([[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]], float) / 8
)
_C_AT_G_ROW = (
    np.array([[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, 0.5, 0, 0]], float) / 8
)  # colour in the same row
_C_AT_G_COL = _C_AT_G_ROW.T  # colour in the same column
_C_AT_OPP = (
    np.array([[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0], [0, 0, -1.5, 0, 0]], float)
    / 8
)  # R at B, B at R

_BILINEAR_RB = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], float) / 4
_BILINEAR_G = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], float) / 4


def _conv(x: np.ndarray, k: np.ndarray) -> np.ndarray:
    # 'mirror' keeps the CFA phase at the border (pixel -1 reflects onto pixel 1).
    return convolve(x, k, mode="mirror")


def demosaick_bilinear(cfa: np.ndarray, pattern: str) -> np.ndarray:
    m = bayer_masks(pattern, *cfa.shape).numpy().astype(cfa.dtype)
    return np.stack(
        [_conv(cfa * m[0], _BILINEAR_RB), _conv(cfa * m[1], _BILINEAR_G), _conv(cfa * m[2], _BILINEAR_RB)], axis=-1
    )


def demosaick_malvar(cfa: np.ndarray, pattern: str) -> np.ndarray:
    m = bayer_masks(pattern, *cfa.shape).numpy().astype(bool)
    g_rb, c_row, c_col, c_opp = (_conv(cfa, k) for k in (_G_AT_RB, _C_AT_G_ROW, _C_AT_G_COL, _C_AT_OPP))
    out = np.empty(cfa.shape + (3,), cfa.dtype)
    out[..., 1] = np.where(m[1], cfa, g_rb)
    for c, _other in ((0, 2), (2, 0)):
        in_row = m[c].any(axis=1, keepdims=True)  # rows that hold this colour
        at_g = np.where(in_row, c_row, c_col)
        out[..., c] = np.where(m[c], cfa, np.where(m[1], at_g, c_opp))
    return out


def default_ccm() -> np.ndarray:
    """Sensor RGB -> linear sRGB matrix of the default sensor (rows sum to 1)."""
    from .ccm import sensor_ccm

    return sensor_ccm()


def run(
    raw: np.ndarray,
    params: dict | None = None,
    *,
    pattern: str = "RGGB",
    adc_bits: int = 12,
    ccm: np.ndarray | None = None,
) -> np.ndarray:
    """RAW [H, W] in digital numbers -> sRGB-like image [H, W, 3] in [0, 1] (8-bit levels)."""
    raw = np.asarray(raw, dtype=np.float64)
    if raw.ndim != 2:
        raise InputError(f"reference ISP expects one RAW frame [H, W], got shape {raw.shape}")
    if not np.all(np.isfinite(raw)):
        raise InputError("reference ISP: RAW frame contains NaN or infinite values")
    p = hp.check(params or {})
    white = 2.0**adc_bits - 1
    x = np.clip((raw - p["black_level_dn"]) / (white - p["black_level_dn"]), 0.0, None)
    m = bayer_masks(pattern, *x.shape).numpy()
    x = x * (1 + (p["wb_red"] - 1) * m[0] + (p["wb_blue"] - 1) * m[2])
    rgb = (demosaick_malvar if int(p["demosaick"]) == 1 else demosaick_bilinear)(x, pattern)
    rgb = np.clip(rgb, 0.0, None)
    if p["denoise_sigma"] > 0:
        rgb = denoise_bilateral(
            rgb, sigma_color=p["denoise_sigma"], sigma_spatial=1.0, win_size=5, channel_axis=2, mode="reflect"
        )
    m_sensor = default_ccm() if ccm is None else np.asarray(ccm, float)
    blend = (1 - p["ccm_strength"]) * np.eye(3) + p["ccm_strength"] * m_sensor
    rgb = np.clip(rgb @ blend.T, 0.0, 1.0)
    rgb = rgb ** (1.0 / p["gamma"])
    if p["sharpen_amount"] > 0:
        rgb = unsharp_mask(
            rgb, radius=p["sharpen_radius_px"], amount=p["sharpen_amount"], channel_axis=2, preserve_range=True
        )
    return np.round(np.clip(rgb, 0.0, 1.0) * 255) / 255


def run_batch(raw, params_list, **kw) -> np.ndarray:
    """[B, 1, H, W] or [B, H, W] RAW (numpy or torch) + list of B dicts -> [B, 3, H, W] float32."""
    raw = np.asarray(raw.detach().cpu() if hasattr(raw, "detach") else raw)
    raw = raw.reshape(raw.shape[0], raw.shape[-2], raw.shape[-1])
    if len(params_list) != raw.shape[0]:
        raise InputError(f"{raw.shape[0]} RAW frames but {len(params_list)} hyperparameter sets")
    return np.stack([run(r, p, **kw).transpose(2, 0, 1) for r, p in zip(raw, params_list)]).astype(np.float32)


class ReferenceISP:
    """Callable wrapper with fixed sensor settings: isp(raw [B,1,H,W], params list) -> [B,3,H,W]."""

    def __init__(self, pattern: str = "RGGB", adc_bits: int = 12, ccm: np.ndarray | None = None):
        self.pattern, self.adc_bits, self.ccm = pattern, adc_bits, ccm

    def __call__(self, raw, params_list) -> torch.Tensor:
        out = run_batch(raw, params_list, pattern=self.pattern, adc_bits=self.adc_bits, ccm=self.ccm)
        return torch.from_numpy(out)
