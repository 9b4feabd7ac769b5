"""Hyperparameters of the reference ("hardware") ISP: names, physical ranges, defaults.

The reference ISP (``reference.py``) reads a plain ``dict`` name -> value. The proxy
(``proxy.py``) sees the same values rescaled to [0, 1] by their range, one constant channel
per hyperparameter (paper Sec. 4.2). Categorical settings (the demosaick method) are coded as
the index of the choice, which the proxy sees as 0 or 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError


@dataclass(frozen=True)
class HyperParam:
    name: str
    low: float
    high: float
    default: float
    unit: str
    doc: str
    choices: tuple[str, ...] = ()  # categorical: value is the index of the choice

    @property
    def categorical(self) -> bool:
        return bool(self.choices)


# Ranges are what a camera tuning engineer would sweep on a 12-bit sensor; the defaults are a
# generic "out of the box" tuning: the datasheet black level and the sensor's colour matrix,
# but unity white balance and mid denoise / sharpening, not the
# optimum for any scene: `optix isp tune` finds better ones through the proxy.
SPACE: tuple[HyperParam, ...] = (
    HyperParam("black_level_dn", 0.0, 128.0, 64.0, "DN", "black level subtracted from the RAW before anything else"),
    HyperParam("wb_red", 1.0, 2.6, 1.0, "x", "white-balance gain of the red pixels"),
    HyperParam("wb_blue", 1.0, 2.6, 1.0, "x", "white-balance gain of the blue pixels"),
    HyperParam("demosaick", 0.0, 1.0, 0.0, "", "demosaicking method", choices=("bilinear", "malvar")),
    HyperParam(
        "denoise_sigma",
        0.0,
        0.12,
        0.04,
        "linear",
        "range sigma of the bilateral denoiser (0 = off), in linear signal units",
    ),
    HyperParam("sharpen_amount", 0.0, 2.0, 0.5, "x", "unsharp-mask amount (0 = off)"),
    HyperParam("sharpen_radius_px", 0.5, 2.5, 1.0, "px", "unsharp-mask Gaussian radius"),
    HyperParam("ccm_strength", 0.0, 1.0, 1.0, "", "blend from identity (0) to the full colour-correction matrix (1)"),
    HyperParam("gamma", 1.6, 2.8, 2.2, "", "display gamma of the tone curve, y = x^(1/gamma)"),
)
NAMES = tuple(p.name for p in SPACE)
_BY_NAME = {p.name: p for p in SPACE}


def defaults() -> dict[str, float]:
    return {p.name: p.default for p in SPACE}


def check(params: dict) -> dict[str, float]:
    """Complete ``params`` with defaults and validate every value against its range."""
    unknown = set(params) - set(NAMES)
    if unknown:
        raise InputError(f"unknown ISP hyperparameter(s) {sorted(unknown)}: expected {list(NAMES)}")
    out = defaults()
    for name, value in params.items():
        p = _BY_NAME[name]
        if p.categorical and isinstance(value, str):
            if value not in p.choices:
                raise InputError(f"ISP hyperparameter {name}: {value!r} is not one of {p.choices}")
            value = p.choices.index(value)
        v = float(value)
        if not np.isfinite(v) or v < p.low - 1e-9 or v > p.high + 1e-9:
            raise InputError(f"ISP hyperparameter {name}={value} outside its range [{p.low}, {p.high}] {p.unit}")
        out[name] = float(round(v)) if p.categorical else v
    return out


def sample(rng: np.random.Generator) -> dict[str, float]:
    """Uniform random hyperparameters over the whole space (categoricals uniform over choices)."""
    return {
        p.name: float(rng.integers(len(p.choices))) if p.categorical else float(rng.uniform(p.low, p.high))
        for p in SPACE
    }


def to_unit(params: dict) -> np.ndarray:
    """dict -> vector in [0, 1]^n (range-normalized), the proxy's conditioning."""
    full = check(params)
    return np.array([(full[p.name] - p.low) / (p.high - p.low) for p in SPACE], dtype=np.float32)


def from_unit(u) -> dict[str, float]:
    """Vector in [0, 1]^n -> dict (categoricals rounded to a valid choice)."""
    u = np.clip(np.asarray(u, dtype=np.float64).reshape(-1), 0.0, 1.0)
    if u.size != len(SPACE):
        raise InputError(f"expected {len(SPACE)} ISP hyperparameters, got {u.size}")
    out = {}
    for p, x in zip(SPACE, u):
        v = p.low + x * (p.high - p.low)
        out[p.name] = float(round(v)) if p.categorical else float(v)
    return out


def describe(params: dict) -> dict:
    """Readable form for JSON: categoricals by name."""
    full = check(params)
    return {p.name: (p.choices[int(full[p.name])] if p.categorical else round(full[p.name], 6)) for p in SPACE}


def unit_tensor(params_list, device=None) -> torch.Tensor:
    """List of dicts -> [B, n] float tensor in [0, 1]."""
    return torch.as_tensor(np.stack([to_unit(p) for p in params_list]), device=device)
