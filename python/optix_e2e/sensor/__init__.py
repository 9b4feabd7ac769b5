"""Differentiable EMVA 1288 sensor model (paper Sec. 3.3), Bayer CFA and photon-transfer analysis."""

from .cfa import PATTERNS, bayer_masks, mosaic
from .emva import (
    Sensor,
    calibrate_radiance_scale,
    dark_current_mean,
    expected_electrons,
    expected_signal,
    raw_from_electrons,
    simulate_raw,
)
from .poisson import poisson_sample
from .presets import PRESETS, SensorPreset, get_preset
from .ptc import photon_transfer, save_ptc
from .spectral import RGBToSpectrum, photon_count_mean, rgb_to_spectrum

__all__ = [
    "PATTERNS",
    "PRESETS",
    "RGBToSpectrum",
    "Sensor",
    "SensorPreset",
    "bayer_masks",
    "calibrate_radiance_scale",
    "dark_current_mean",
    "expected_electrons",
    "raw_from_electrons",
    "expected_signal",
    "get_preset",
    "mosaic",
    "photon_count_mean",
    "photon_transfer",
    "poisson_sample",
    "rgb_to_spectrum",
    "save_ptc",
    "simulate_raw",
]
