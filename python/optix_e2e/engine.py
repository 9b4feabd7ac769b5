"""The Rust engine's one door (docs/architecture.md): every call into the compiled extension
goes through these keyword-only wrappers, so what crosses into Rust is written in one place
and every argument is named at the call. The units, keys and guarantees of each function are
documented in ``_engine.pyi`` (checked against the built module by tests/engine/test_engine_stub.py).

The lens is always the resolved JSON prescription (``Lens.to_engine_json()``); arrays are
float64 and C-contiguous (converted here); errors are the extension's own classes, re-exported
below: ``EngineError`` and its subclasses ``LensError``, ``MaterialError``, ``TraceError``,
``PsfError``, and ``ArgumentError`` (defined here, also a ``ValueError``) for a value the engine
refuses as an argument (a size, a sample count, a field angle, a method name), which the
extension raises as a plain ``ValueError``. The command line prints every ``EngineError`` as one
line (cli/_common.py).
"""

from __future__ import annotations

import functools
from typing import Any, Sequence

import numpy as np

from . import _engine as _ext
from ._engine import EngineError, LensError, MaterialError, PsfError, TraceError

__all__ = [
    "ArgumentError",
    "EngineError",
    "LensError",
    "MaterialError",
    "PsfError",
    "TraceError",
    "auto_candidates",
    "available_memory",
    "best_focus_batch",
    "crc32",
    "paraxial",
    "predicted_psf_seconds",
    "extension_file",
    "field_fold",
    "psf",
    "psf_batch",
    "psf_rgb",
    "psf_set_vjp",
    "refractive_indices",
    "spot",
    "trace",
    "trace_field",
    "trace_field_path",
    "validate_lens",
    "wavefront",
]

Channels = Sequence[Sequence[tuple[float, float]]]


class ArgumentError(EngineError, ValueError):
    """A value the engine refuses as an argument; the message says which and why."""


def _door(fn):
    """Re-raise the extension's plain ``ValueError`` (a refused argument) as ``ArgumentError``."""

    @functools.wraps(fn)
    def call(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except ValueError as exc:
            if isinstance(exc, EngineError):
                raise
            raise ArgumentError(str(exc)) from None

    return call


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


@_door
def validate_lens(lens_json: str) -> None:
    _ext.validate_lens(lens_json)


@_door
def refractive_indices(lens_json: str, *, wavelength_nm: float) -> np.ndarray:
    return _ext.refractive_indices(lens_json, float(wavelength_nm))


@_door
def paraxial(lens_json: str, *, wavelength_nm: float | None = None) -> dict[str, float]:
    return _ext.paraxial(lens_json, None if wavelength_nm is None else float(wavelength_nm))


@_door
def trace(lens_json: str, *, origins, directions, wavelength_nm: float) -> dict[str, np.ndarray]:
    return _ext.trace(lens_json, _f64(origins), _f64(directions), float(wavelength_nm))


@_door
def trace_field(
    lens_json: str, *, field_deg: float, px, py, wavelength_nm: float, aiming: str = "paraxial"
) -> dict[str, np.ndarray]:
    return _ext.trace_field(lens_json, float(field_deg), _f64(px), _f64(py), float(wavelength_nm), aiming)


@_door
def trace_field_path(
    lens_json: str, *, field_deg: float, px, py, wavelength_nm: float, aiming: str = "paraxial"
) -> dict[str, np.ndarray]:
    return _ext.trace_field_path(lens_json, float(field_deg), _f64(px), _f64(py), float(wavelength_nm), aiming)


@_door
def wavefront(
    lens_json: str,
    *,
    field_deg: float,
    px,
    py,
    weights,
    wavelengths_nm: Sequence[float],
    wavelength_weights: Sequence[float] | None = None,
    aiming: str = "paraxial",
    tilt: str = "wavelength",
) -> dict[str, Any]:
    return _ext.wavefront(
        lens_json,
        float(field_deg),
        _f64(px),
        _f64(py),
        _f64(weights),
        [float(w) for w in wavelengths_nm],
        None if wavelength_weights is None else [float(w) for w in wavelength_weights],
        aiming,
        tilt,
    )


@_door
def spot(
    lens_json: str,
    *,
    field_deg: float,
    wavelengths_nm: Sequence[float],
    weights: Sequence[float] | None = None,
    rings: int = 64,
    aiming: str = "paraxial",
) -> dict[str, Any]:
    return _ext.spot(
        lens_json,
        float(field_deg),
        [float(w) for w in wavelengths_nm],
        None if weights is None else [float(w) for w in weights],
        int(rings),
        aiming,
    )


@_door
def field_fold(
    lens_json: str, *, field_max_deg: float, wavelength_nm: float | None = None, aiming: str = "paraxial"
) -> dict[str, float] | None:
    return _ext.field_fold(
        lens_json, float(field_max_deg), None if wavelength_nm is None else float(wavelength_nm), aiming
    )


@_door
def ray_footprint(
    lens_json: str,
    *,
    n_surfaces: int,
    fields_deg: Sequence[float],
    wavelengths_nm: Sequence[float],
    px,
    py,
    aiming: str = "paraxial",
) -> np.ndarray:
    """Clear semi-diameters from the ray footprint, as Zemax's automatic semi-diameters:
    (n_surfaces,) largest radial height at each surface of the pupil rays (px, py) of every
    field and wavelength, in one call (0 where no ray gets there).

    Only rays that reach the image count: a ray that misses a surface or is totally reflected
    does not pass the lens at that field, and its path on the surfaces before (far out on an
    extended sphere, say) would size them for light that never arrives."""
    return _ext.ray_footprint(
        lens_json,
        int(n_surfaces),
        [float(f) for f in fields_deg],
        [float(w) for w in wavelengths_nm],
        _f64(px),
        _f64(py),
        aiming,
    )


@_door
def chief_ray_status(
    lens_json: str, *, fields_deg: Sequence[float], wavelengths_nm: Sequence[float], aiming: str = "paraxial"
) -> list[int | str]:
    """The chief ray's status code (0 ok, 1 missed a surface, 2 clipped, 3 totally reflected,
    4 invalid) at each field and wavelength, fields outer, in one call; where its beam cannot
    be launched, the engine's message instead."""
    return _ext.chief_ray_status(lens_json, [float(f) for f in fields_deg], [float(w) for w in wavelengths_nm], aiming)


@_door
def psf(
    lens_json: str,
    *,
    field_deg: float,
    wavelength_nm: float,
    method: str = "fft",
    pixel_um: float = 1.0,
    size: int = 64,
    pupil_samples: int = 64,
    fft_grid: int | None = None,
    aiming: str = "paraxial",
    integrate: bool = False,
    exact: bool = False,
    fast: bool = False,
    accuracy: float = 0.02,
    progress=None,
) -> tuple[np.ndarray, dict[str, Any]]:
    return _ext.psf(
        lens_json,
        float(field_deg),
        float(wavelength_nm),
        method,
        float(pixel_um),
        int(size),
        int(pupil_samples),
        fft_grid,
        aiming,
        bool(integrate),
        bool(exact),
        bool(fast),
        float(accuracy),
        progress,
    )


@_door
def psf_rgb(
    lens_json: str,
    *,
    field_deg: float,
    channels: Channels,
    method: str = "fft",
    pixel_um: float = 1.0,
    size: int = 64,
    pupil_samples: int = 64,
    aiming: str = "paraxial",
    integrate: bool = False,
    fast: bool = True,
    accuracy: float = 0.02,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    return _ext.psf_rgb(
        lens_json,
        float(field_deg),
        channels,
        method,
        float(pixel_um),
        int(size),
        int(pupil_samples),
        aiming,
        bool(integrate),
        bool(fast),
        float(accuracy),
    )


@_door
def psf_batch(
    lens_jsons: Sequence[str],
    *,
    fields_deg: Sequence[float],
    channels: Channels,
    method: str = "fft",
    pixel_um: float = 1.0,
    size: int = 64,
    pupil_samples: int = 64,
    aiming: str = "paraxial",
    integrate: bool = False,
    fast: bool = True,
    out: np.ndarray | None = None,
    sensor=None,
    sensor_out: np.ndarray | None = None,
    accuracy: float = 0.02,
) -> dict[str, Any]:
    return _ext.psf_batch(
        list(lens_jsons),
        [float(f) for f in fields_deg],
        channels,
        method,
        float(pixel_um),
        int(size),
        int(pupil_samples),
        aiming,
        bool(integrate),
        bool(fast),
        out,
        sensor,
        sensor_out,
        float(accuracy),
    )


@_door
def auto_candidates(
    lens_json: str,
    *,
    field_deg: float,
    wavelength_nm: float,
    pixel_um: float = 1.0,
    size: int = 64,
    aiming: str = "paraxial",
    integrate: bool = False,
) -> dict[str, Any]:
    return _ext.auto_candidates(
        lens_json, float(field_deg), float(wavelength_nm), float(pixel_um), int(size), aiming, bool(integrate)
    )


@_door
def best_focus_batch(
    lens_jsons: Sequence[str],
    *,
    fields_deg: Sequence[float],
    wavelengths: Sequence[tuple[float, float]],
    rings: int = 8,
    aiming: str = "paraxial",
) -> dict[str, Any]:
    return _ext.best_focus_batch(
        list(lens_jsons),
        [float(f) for f in fields_deg],
        [(float(w), float(k)) for w, k in wavelengths],
        int(rings),
        aiming,
    )


@_door
def psf_set_vjp(
    *,
    lens_json: str,
    fields_deg: Sequence[float],
    channels: Channels,
    params: Sequence[tuple[str, int, int]],
    g_psf: np.ndarray,
    g_ri: np.ndarray,
    method: str = "auto",
    pixel_um: float = 1.0,
    size: int = 64,
    pupil_samples: int = 64,
    aiming: str = "paraxial",
    accuracy: float = 0.02,
    sensor: tuple[float, int] | None = None,
    focus: tuple[Sequence[float], Sequence[tuple[float, float]], int] | None = None,
) -> dict[str, Any]:
    return _ext.psf_set_vjp(
        lens_json,
        [float(f) for f in fields_deg],
        [[(float(w), float(k)) for w, k in c] for c in channels],
        [(str(k), int(s), int(t)) for k, s, t in params],
        np.ascontiguousarray(g_psf, np.float64),
        np.ascontiguousarray(g_ri, np.float64),
        method,
        float(pixel_um),
        int(size),
        int(pupil_samples),
        aiming,
        float(accuracy),
        None if sensor is None else (float(sensor[0]), int(sensor[1])),
        None
        if focus is None
        else ([float(f) for f in focus[0]], [(float(w), float(k)) for w, k in focus[1]], int(focus[2])),
    )


@_door
def crc32(data: np.ndarray, *, crc: int = 0) -> int:
    return _ext.crc32(data, int(crc))


@_door
def predicted_psf_seconds(
    *, method: str, pixel_um: float, size: int, pupil_samples: int, fft_grid: int | None = None, n_surfaces: int = 10
) -> float | None:
    return _ext.predicted_psf_seconds(method, float(pixel_um), int(size), int(pupil_samples), fft_grid, int(n_surfaces))


@_door
def available_memory() -> float:
    return _ext.available_memory()


@_door
def extension_file() -> str:
    """The compiled extension's file (Dask workers compare its digest with the client's)."""
    return _ext.__file__
