"""Sensor calibrations (EMVA 1288 parameters) as frozen dataclasses.

``imx249``: a Sony IMX249-class global-shutter colour sensor (1920x1200, 5.86 um pixels, 12-bit
ADC, ~32.5k e- full well, ~7 e- read noise). The system gain K is chosen so that full well lands
just below the ADC maximum (64 + 0.12 * 32513 = 3966 DN < 4095): the sensor saturates before the
ADC clips, as on a camera at its base gain.
``phone-1um``: a small-pixel smartphone-class sensor (1.0 um pixels, 10-bit, 4.5k e-).

``radiance_scale`` maps a linear RGB value of 1.0 to a spectral radiance in W m^-2 sr^-1 nm^-1.
Each preset's value is set (``emva.calibrate_radiance_scale``) so that a (1, 1, 1) input gives
85% of full well in the green channel at the preset's own exposure and f-number.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch

from ..errors import InputError
from .cfa import check_pattern

ABSOLUTE_ZERO_C = -273.15


def check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    """``value`` as a float if finite and > 0 (>= 0 with allow_zero), else ValueError naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        what = "non-negative" if allow_zero else "positive"
        raise InputError(f"{name} must be {what} and finite, got {value!r}")
    return v


@dataclass(frozen=True)
class SensorPreset:
    name: str = "imx249"
    width: int = 1920
    height: int = 1200
    pixel_um: float = 5.86
    adc_bits: int = 12
    full_well_e: float = 32513.0  # e_SAT of Eq. 5
    dark_noise_e: float = 7.0  # sigma_d of Eq. 5 (temporal read noise, e-)
    gain_dn_per_e: float = 0.12  # K of Eq. 5 (DN / e-)
    black_level_dn: float = 64.0  # b of Eq. 5
    dark_current_e_per_s: float = 5.0  # mu_I.ref of Eq. 4 at t_ref_c
    t_ref_c: float = 25.0
    doubling_c: float = 7.0  # T_d of Eq. 4
    temperature_c: float = 25.0
    exposure_s: float = 5e-3
    f_number: float = 4.0
    cfa: str = "RGGB"
    qe_peak: float = 0.70  # peak of the green QE curve
    # Per-channel QE (R, G, B): Gaussian bands times a smooth IR-cut filter edge.
    qe_center_nm: tuple = (605.0, 535.0, 460.0)
    qe_sigma_nm: tuple = (30.0, 40.0, 30.0)
    qe_relative: tuple = (0.90, 1.0, 0.85)
    ir_cut_nm: float = 650.0
    ir_cut_width_nm: float = 10.0
    radiance_scale: float = 0.017720  # W m^-2 sr^-1 nm^-1 per unit of linear RGB

    def __post_init__(self):
        for f in (
            "pixel_um",
            "full_well_e",
            "gain_dn_per_e",
            "doubling_c",
            "exposure_s",
            "f_number",
            "qe_peak",
            "ir_cut_nm",
            "ir_cut_width_nm",
            "radiance_scale",
        ):
            check_positive(f, getattr(self, f))
        for f in ("dark_noise_e", "black_level_dn", "dark_current_e_per_s"):
            check_positive(f, getattr(self, f), allow_zero=True)
        for f in ("t_ref_c", "temperature_c"):
            t = float(getattr(self, f))
            if not math.isfinite(t) or t < ABSOLUTE_ZERO_C:
                raise InputError(
                    f"{f} must be finite and at least {ABSOLUTE_ZERO_C} C (absolute zero), got {getattr(self, f)!r}"
                )
        try:  # Eq. 4 doubles the dark current every doubling_c: it must stay a float
            rate = self.dark_current_rate_e_per_s
        except OverflowError:
            rate = math.inf
        if not math.isfinite(rate):
            raise InputError(
                f"temperature_c = {self.temperature_c:g} C: the dark current "
                f"{self.dark_current_e_per_s:g} e-/s doubling every {self.doubling_c:g} C from "
                f"{self.t_ref_c:g} C (Eq. 4) overflows"
            )
        for f in ("width", "height", "adc_bits"):
            v = getattr(self, f)
            if not isinstance(v, int) or v < 1:
                raise InputError(f"{f} must be a positive integer, got {v!r}")
        if self.adc_bits > 24:
            raise InputError(f"adc_bits must be at most 24, got {self.adc_bits}")
        if self.qe_peak > 1:
            raise InputError(f"qe_peak must be at most 1, got {self.qe_peak}")
        if self.black_level_dn >= self.adc_max_dn:
            raise InputError(f"black_level_dn ({self.black_level_dn}) must be below the ADC maximum {self.adc_max_dn}")
        for f in ("qe_center_nm", "qe_sigma_nm", "qe_relative"):
            v = getattr(self, f)
            if len(v) != 3:
                raise InputError(f"{f} needs 3 values (R, G, B), got {v!r}")
            for x in v:
                check_positive(f, x)
        try:
            object.__setattr__(self, "cfa", check_pattern(self.cfa))
        except (ValueError, AttributeError) as exc:
            raise InputError(f"cfa: {exc}") from None

    @property
    def dark_current_rate_e_per_s(self) -> float:
        """Eq. 4's mu_I.ref * 2^((T - T_ref) / T_d): the dark current at temperature_c (e-/s)."""
        return self.dark_current_e_per_s * 2.0 ** ((self.temperature_c - self.t_ref_c) / self.doubling_c)

    @property
    def adc_max_dn(self) -> int:
        return 2**self.adc_bits - 1

    @property
    def saturation_e(self) -> float:
        """Electrons where the output saturates: full well, or the ADC maximum if that comes first."""
        return min(self.full_well_e, (self.adc_max_dn - self.black_level_dn) / self.gain_dn_per_e)

    @property
    def adc_limited(self) -> bool:
        return self.saturation_e < self.full_well_e

    def qe_curves(self, wavelengths_nm) -> torch.Tensor:
        """Quantum efficiency eta(lambda) [3, L] (R, G, B) in float64, including the IR-cut filter."""
        lam = torch.as_tensor(wavelengths_nm, dtype=torch.float64)
        c = torch.tensor(self.qe_center_nm, dtype=torch.float64)[:, None]
        s = torch.tensor(self.qe_sigma_nm, dtype=torch.float64)[:, None]
        r = torch.tensor(self.qe_relative, dtype=torch.float64)[:, None]
        band = torch.exp(-0.5 * ((lam - c) / s) ** 2)
        ir_cut = torch.sigmoid((self.ir_cut_nm - lam) / self.ir_cut_width_nm)
        return self.qe_peak * r * band * ir_cut

    def with_(self, **changes) -> "SensorPreset":
        """A copy with some fields changed (validated)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise InputError(f"unknown SensorPreset field(s): {', '.join(sorted(unknown))}")
        return dataclasses.replace(self, **changes)

    def low_light(self, factor: float = 100.0) -> "SensorPreset":
        """The paper's low-light setting: exposure / factor and gain K * factor (same mean DN)."""
        factor = check_positive("factor", factor)
        return self.with_(
            name=f"{self.name}-lowlight{factor:g}",
            exposure_s=self.exposure_s / factor,
            gain_dn_per_e=self.gain_dn_per_e * factor,
        )


PRESETS: dict[str, SensorPreset] = {
    "imx249": SensorPreset(),
    "phone-1um": SensorPreset(
        name="phone-1um",
        width=4000,
        height=3000,
        pixel_um=1.0,
        adc_bits=10,
        full_well_e=4500.0,
        dark_noise_e=2.0,
        gain_dn_per_e=0.2,
        black_level_dn=64.0,
        dark_current_e_per_s=20.0,
        doubling_c=6.0,
        exposure_s=10e-3,
        f_number=1.8,
        qe_peak=0.65,
        radiance_scale=0.009739,
    ),
}


def get_preset(name) -> SensorPreset:
    """A preset by name (case-insensitive); a SensorPreset passes through."""
    if isinstance(name, SensorPreset):
        return name
    key = str(name).lower()
    if key not in PRESETS:
        raise InputError(f"unknown sensor preset {name!r}: known presets are {', '.join(PRESETS)}")
    return PRESETS[key]
