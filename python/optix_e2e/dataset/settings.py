"""Settings of a PSF dataset and the pieces derived from them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..lens import Lens

# The engine's largest PSF (pixels across; crates/psf-engine PsfOptions::check).
MAX_SIZE = 8192


def human(b: float) -> str:
    """Bytes as a short figure (GiB or TiB)."""
    return f"{b / 2**40:.1f} TiB" if b >= 2**40 else f"{b / 2**30:.1f} GiB"


FOCUS_WITHIN = ("bfd", "none")
# what a manifest made before a setting existed did, where that is not today's default: such a
# manifest has no key (_request leaves it out when it has this value)
BEFORE_KEY = {"focus_within": "none"}


@dataclass(frozen=True)
class DatasetSettings:
    """What each design's record holds and how it is computed."""

    n_fields: int = 13  # K field positions, uniform along +y from 0 to the full field; 0: auto
    window_um: float = 128.0  # super-resolved PSF window (side)
    pixel_um: float = 1.0  # ... and its pitch
    sensor_pixel_um: float = 5.86  # the sensor-pitch version (IMX249 pixels)
    pupil_samples: int = 64
    psf_method: str = "auto"  # per PSF: the cheapest method and sampling predicted to meet `accuracy`
    accuracy: float = 0.02  # method auto: target relative L1 error of each monochromatic PSF
    aiming: str = "paraxial"
    channels: str = "lens"  # "lens": the lens's three wavelengths -> R, G, B; "rgb": 3 per channel
    shard_size: int = 64
    sampling: str = "sobol"
    apertures: str = "auto"  # "auto": no clear apertures (Zemax's automatic semi-diameters,
    # every surface passes the beam); "fixed": the base lens's, stop excepted
    focus: str = "best"  # image plane per design: "best" (least RMS spot over the K fields
    # and the channels' wavelengths), "paraxial", or "fixed" (the base's)
    # best focus from this many of the K fields and rings of a polar pupil: 7 and 4 are within
    # 1 um of all fields and 8 rings near the nominal; a wide space's designs need the finer
    # sampling (OpticsSurrogate.in_space sets 13 and 8: camera_design/outputs.focus_check's)
    focus_fields: int = 7
    focus_rings: int = 4
    # where the focus may put the image plane: "bfd", no nearer the last surface than the
    # space's back-focus limit (its [constraints] min_bfd: the sensor sits behind it), or
    # "none", wherever it falls (a plane inside the last surface fails the design): every
    # dataset's rule before 2026-11-28, whose manifests have no key (``of_manifest``)
    focus_within: str = "bfd"

    @classmethod
    def of_manifest(cls, settings: dict) -> "DatasetSettings":
        """The settings a manifest records (a key it lacks: the rule before the key existed)."""
        return cls(**{**BEFORE_KEY, **settings})

    @classmethod
    def recorded(cls, settings: dict, k: str):
        """A manifest's setting ``k`` as ``of_manifest`` reads it, without checking the others."""
        return settings.get(k, BEFORE_KEY.get(k, getattr(cls, k, None)))

    def check(self) -> None:
        if self.n_fields < 0:
            raise InputError(f"n_fields must be >= 1 (or 0: auto), got {self.n_fields}")
        if not (self.window_um > 0 and self.pixel_um > 0 and self.sensor_pixel_um > 0):
            raise InputError("window_um, pixel_um and sensor_pixel_um must be positive")
        if self.size < 8:
            raise InputError(f"window {self.window_um} um at {self.pixel_um} um/pixel is only {self.size} pixels")
        if self.size > MAX_SIZE:
            raise InputError(
                f"window {self.window_um} um at {self.pixel_um} um/pixel is {self.size} pixels across; "
                f"the engine computes at most {MAX_SIZE} (a smaller window_um or a larger pixel_um)"
            )
        if self.sensor_size < 1:
            raise InputError(f"window {self.window_um} um holds no {self.sensor_pixel_um} um sensor pixel")
        if self.shard_size < 1:
            raise InputError(f"shard_size must be >= 1, got {self.shard_size}")
        if self.apertures not in ("auto", "fixed"):
            raise InputError(f"apertures must be 'auto' or 'fixed', got {self.apertures!r}")
        if self.focus not in ("best", "paraxial", "fixed"):
            raise InputError(f"focus must be 'best', 'paraxial' or 'fixed', got {self.focus!r}")
        if self.focus_within not in FOCUS_WITHIN:
            raise InputError(f"focus_within must be one of {', '.join(FOCUS_WITHIN)}, got {self.focus_within!r}")
        if self.focus_fields < 1 or self.focus_rings < 1:
            raise InputError(f"focus_fields and focus_rings must be >= 1, got {self.focus_fields}, {self.focus_rings}")
        if self.psf_method not in ("auto", "fft", "huygens", "geometric"):
            raise InputError(f"psf_method must be auto, fft, huygens or geometric, got {self.psf_method!r}")
        if not self.accuracy > 0:
            raise InputError(f"accuracy must be a positive relative L1 error, got {self.accuracy}")
        if self.channels not in ("lens", "rgb", "auto"):
            raise InputError(f"channels must be 'lens', 'rgb' or 'auto', got {self.channels!r}")

    def check_memory(self, n_designs: int, n_fields: int, n_channels: int) -> None:
        """Refuse, before anything is written, settings whose shard buffers (PSFs and sensor
        PSFs of one shard, float32) and the engine's per-thread work exceed the memory
        available; the message says what they would need."""
        import os

        from .. import engine

        rows = min(self.shard_size, n_designs) * n_fields * n_channels
        buffers = rows * (self.size**2 + self.sensor_size**2) * 4.0
        work = (os.cpu_count() or 1) * (self.size**2 * 24.0 + (4 * self.pupil_samples) ** 2 * 32.0)
        avail = engine.available_memory()
        if buffers + work > avail:
            raise InputError(
                f"a shard of {min(self.shard_size, n_designs)} designs x {n_fields} fields x {n_channels} "
                f"channels at {self.size}x{self.size} pixels would need about {human(buffers + work)} "
                f"(shard buffers {human(buffers)}), more than the {human(avail)} of memory available: "
                f"lower --window-um or --shard-size, or raise --pixel-um"
            )

    @property
    def size(self) -> int:
        return int(round(self.window_um / self.pixel_um))

    @property
    def sensor_size(self) -> int:
        """Whole sensor pixels inside the window, odd so one is centred on the chief ray."""
        s = int(math.floor(self.window_um / self.sensor_pixel_um + 1e-9))
        return s if s % 2 else s - 1


def field_positions(base: Lens, k: int) -> list[float]:
    return [float(f) for f in np.linspace(0.0, base.max_field_deg, k)]
