"""sRGB transfer functions and the ColorChecker reference colours.

Images in optix_e2e are float tensors in [0, 1], gamma-encoded sRGB unless a function says
"linear".  The transfer curve is the piecewise one of IEC 61966-2-1:1999 (sRGB).  Both
directions are differentiable everywhere and NaN-free: the power branch is evaluated on an
input clamped into its own domain, so ``torch.where`` never back-propagates through a power
of a negative number (or of zero, where x**(1/2.4) has an infinite slope).  Values below 0
follow the linear toe segment (gradients survive instead of being cut by a clamp); values
above 1 follow the power segment.
"""

from __future__ import annotations

import torch

__all__ = ["srgb_to_linear", "linear_to_srgb", "COLORCHECKER_NAMES", "COLORCHECKER_SRGB8", "colorchecker_srgb"]

_A = 0.055
_ENC_KNEE = 0.04045  # encoded value where the curve changes from linear to power
_LIN_KNEE = 0.0031308  # the same point in linear light


def srgb_to_linear(x: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded values -> linear light (IEC 61966-2-1 decoding)."""
    power = ((x.clamp(min=_ENC_KNEE) + _A) / (1 + _A)) ** 2.4
    return torch.where(x <= _ENC_KNEE, x / 12.92, power)


def linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    """Linear light -> sRGB-encoded values (IEC 61966-2-1 encoding)."""
    power = (1 + _A) * x.clamp(min=_LIN_KNEE) ** (1 / 2.4) - _A
    return torch.where(x <= _LIN_KNEE, x * 12.92, power)


# X-Rite (formerly GretagMacbeth) ColorChecker Classic, row by row from the top-left patch
# (dark skin) as the chart is normally viewed: 4 rows x 6 columns.
COLORCHECKER_NAMES: tuple[str, ...] = (
    "dark skin",
    "light skin",
    "blue sky",
    "foliage",
    "blue flower",
    "bluish green",
    "orange",
    "purplish blue",
    "moderate red",
    "purple",
    "yellow green",
    "orange yellow",
    "blue",
    "green",
    "red",
    "yellow",
    "magenta",
    "cyan",
    "white 9.5",
    "neutral 8",
    "neutral 6.5",
    "neutral 5",
    "neutral 3.5",
    "black 2",
)

# 8-bit sRGB (D65) values of the BabelColor Average: the mean of 30 measured charts, from
# D. Pascale, "ColorChecker RGB and spectra" (BabelColor, 2012,
# http://www.babelcolor.com/download/ColorChecker_RGB_and_spectra.xls, summarised on
# http://www.babelcolor.com/main_level/ColorChecker.htm; method in Pascale, "RGB coordinates
# of the Macbeth ColorChecker", 2006).  Cross-checked here against the BabelColor Average xyY (D50)
# data shipped by colour-science, adapted to D65 with the Bradford transform and encoded
# with srgb: all channels agree within 5/255 (the xyY data are rounded to 4 decimals).
# Cyan's red channel is out of the sRGB gamut and clipped to 0.
COLORCHECKER_SRGB8: tuple[tuple[int, int, int], ...] = (
    (115, 81, 67),
    (196, 149, 129),
    (93, 123, 157),
    (90, 108, 65),
    (130, 129, 176),
    (99, 191, 171),
    (220, 123, 45),
    (72, 92, 168),
    (195, 84, 98),
    (91, 59, 105),
    (160, 189, 62),
    (229, 161, 41),
    (43, 62, 147),
    (71, 149, 72),
    (176, 48, 56),
    (238, 200, 22),
    (188, 84, 150),
    (0, 136, 166),
    (245, 245, 240),
    (200, 201, 201),
    (160, 161, 161),
    (120, 121, 121),
    (83, 84, 85),
    (50, 50, 50),
)


def colorchecker_srgb(linear: bool = False) -> torch.Tensor:
    """The 24 ColorChecker patches as a float32 tensor [24, 3] in [0, 1] (sRGB, or linear)."""
    rgb = torch.tensor(COLORCHECKER_SRGB8, dtype=torch.float32) / 255.0
    return srgb_to_linear(rgb) if linear else rgb
