"""The sensor's colour-correction matrix: camera RGB -> linear sRGB, fitted on a ColorChecker.

The 24 patches (linear sRGB) go through the noise-free sensor model; the R, G and B pixels'
responses (black level removed, white-balanced on the white patch) are the camera RGB.
Least squares gives the 3x3 matrix; its rows are then scaled to sum to 1 so that neutrals
stay neutral, as an ISP's CCM does.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from .. import color
from ..sensor import get_preset
from ..sensor.emva import expected_electrons, raw_from_electrons


def camera_rgb(linear_rgb: np.ndarray, preset_name: str = "imx249") -> np.ndarray:
    """Noise-free camera response (DN above black) of the R, G and B pixels to patches [N, 3] -> [N, 3]."""
    preset = get_preset(preset_name)
    patches = torch.as_tensor(linear_rgb, dtype=torch.float32)[:, :, None, None]
    electrons = expected_electrons(patches, preset)  # per channel, before the CFA picks one
    raw = raw_from_electrons(electrons, preset, noise=False, quantize="none")[:, :, 0, 0].double()
    return (raw - preset.black_level_dn).numpy()


@functools.lru_cache(maxsize=8)
def sensor_ccm(preset_name: str = "imx249") -> np.ndarray:
    target = color.colorchecker_srgb(linear=True).double().numpy()
    cam = camera_rgb(target * 0.8, preset_name)  # exposed so the white patch stays below full well
    white = int(np.argmax(target.sum(1)))
    cam = cam / cam[white] * target[white]  # white balance on the white patch
    m, *_ = np.linalg.lstsq(cam, target, rcond=None)
    m = m.T
    return m / m.sum(axis=1, keepdims=True)
