"""Type stub of the compiled Rust engine (crates/psf-engine-py).

Conventions shared by every function:

* ``lens_json`` is a *resolved* prescription in the JSON schema of docs/lens-format.md:
  every material is ``"air"``, ``{"n": ...}``, ``{"nd": ..., "vd": ...}``,
  ``{"formula": k, "coefficients": [...], "range_um": [lo, hi]}`` (refractiveindex.info
  dispersion formulas 1-9) or ``{"tabulated": [[wl_um, n], ...]}``.  Catalog names
  (``"N-SF11"``, ``{"glass": ..., "catalog": ...}``) are resolved on the Python side by
  :class:`optix_e2e.lens.Lens` before the JSON reaches the engine.
* Lengths are millimetres unless a name says ``_um``; wavelengths are nanometres
  (``wavelength_nm``); field angles are degrees along +y, object at infinity.
* Global frame: first surface vertex at z = 0, image plane at z = total track.
* Ray status codes (uint8): 0 ok, 1 missed a surface, 2 clipped by a clear aperture,
  3 total internal reflection, 4 invalid (non-finite input).  Failed rays carry the
  index of the surface where they failed and zeros in their numeric fields, never NaN.
* PSF arrays: row index = image y, column index = image x, pixel (size//2, size//2) is
  centred on the chief-ray image point; each pixel holds the fraction of the
  entrance-pupil flux that lands in it, so ``psf.sum()`` is the transmitted energy
  inside the window (<= 1).
* ``aiming`` is ``"paraxial"`` (launch through the paraxial entrance pupil) or
  ``"real"`` (each ray iterated onto the real stop).
"""

from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

__version__: str
simd: str
"""Vector instruction set the ray-trace kernel uses here: "avx512", "avx2" or "baseline"."""

class EngineError(Exception):
    """Base class of every error raised by the engine."""

class LensError(EngineError):
    """Invalid prescription; the message names the surface index and parameter."""

class MaterialError(LensError):
    """Unusable material (bad coefficients, wavelength outside its valid range)."""

class TraceError(EngineError):
    """A trace that cannot produce a result (e.g. the chief ray fails, aiming diverges)."""

class PsfError(EngineError):
    """A PSF that cannot be computed (no transmitted rays, bad sampling parameters)."""

def validate_lens(lens_json: str) -> None: ...
def refractive_indices(lens_json: str, wavelength_nm: float) -> NDArray[np.float64]:
    """Index of the medium after each surface; element 0 is object space."""

def paraxial(lens_json: str, wavelength_nm: float | None = None) -> dict[str, float]:
    """First-order data at ``wavelength_nm`` (default: the lens's primary wavelength).

    Keys: efl_mm, bfl_mm (last vertex to paraxial focus), ffl_mm, f_number (EFL/EPD),
    epd_mm, entrance_pupil_z_mm (from first vertex), xpd_mm, exit_pupil_z_mm
    (relative to the image plane), stop_semi_diameter_mm, total_track_mm,
    image_z_mm, paraxial_image_height_mm (EFL*tan(max field); for a finite object the
    chief ray's height at the object's paraxial image), back_focus_shift_mm (paraxial
    focus, or the paraxial image of a finite object, minus image plane),
    object_to_pupil_mm (object plane to entrance pupil; inf for an object at infinity).
    """

def trace(
    lens_json: str,
    origins: NDArray[np.float64],
    directions: NDArray[np.float64],
    wavelength_nm: float,
) -> dict[str, NDArray[Any]]:
    """Trace arbitrary rays (n, 3) from object space to the image plane.

    Returns position (n, 3), direction (n, 3) at the image plane, opl (n,) from the
    origin, status (n,) uint8 and surface (n,) int32 (failing surface or -1).
    """

def trace_field(
    lens_json: str,
    field_deg: float,
    px: NDArray[np.float64],
    py_: NDArray[np.float64],
    wavelength_nm: float,
    aiming: str = "paraxial",
) -> dict[str, NDArray[Any]]:
    """Aim and trace rays at normalized pupil coordinates (px, py) for one field.

    Same keys as :func:`trace` plus origin (n, 3) and launch_direction (n, 3), a
    read-only broadcast view of the one beam direction (for a finite object, each ray's
    own direction: the rays leave one object point).
    """

def trace_field_path(
    lens_json: str,
    field_deg: float,
    px: NDArray[np.float64],
    py_: NDArray[np.float64],
    wavelength_nm: float,
    aiming: str = "paraxial",
) -> dict[str, NDArray[Any]]:
    """Like :func:`trace_field`, plus each ray's path through every surface (for layouts).

    Extra keys: path (n, n_surfaces + 1, 3), the global intersection point with each
    surface and, last, the image plane; last (n,) int32, the index of each ray's last
    valid point (-1: none), with zeros after it; launch_direction (3,), or (n, 3) for a
    finite object.  A ray that
    reaches the image has last = n_surfaces and path[:, -1] equal to ``position`` (bit
    for bit the :func:`trace_field` result).  A failed ray stops where it failed: a
    clipped ray at its hit point on the clipping surface (outside its clear aperture),
    a TIR ray where it reflected, a ray that missed surface i at surface i - 1.
    status and surface are those of the image-plane trace.
    """

def wavefront(
    lens_json: str,
    field_deg: float,
    px: NDArray[np.float64],
    py_: NDArray[np.float64],
    weights: NDArray[np.float64],
    wavelengths_nm: Sequence[float],
    wavelength_weights: Sequence[float] | None = None,
    aiming: str = "paraxial",
    tilt: str = "wavelength",
) -> dict[str, Any]:
    """Wavefront error (OPD) of pupil rays (px, py, weights) of one field at each wavelength,
    against the reference sphere about the primary chief ray's image point through the
    exit pupil; piston removed per wavelength, tilt per wavelength (``tilt="wavelength"``,
    OpticStudio's centroid reference) or one for the field (``"field"``: lateral colour
    stays).  Keys: opd_waves (n_wavelengths, n) in waves of each wavelength, 0 where the
    ray failed; status (n_wavelengths, n) uint8; rms_waves (n_wavelengths,) weighted over
    the transmitted rays; tilt_mm (n_wavelengths, 2); chief_image_mm; reference_radius_mm.
    The per-ray arrays are the engine's own buffers (no copy)."""

def spot(
    lens_json: str,
    field_deg: float,
    wavelengths_nm: Sequence[float],
    weights: Sequence[float] | None = None,
    rings: int = 64,
    aiming: str = "paraxial",
) -> dict[str, Any]:
    """Spot diagram statistics on a hexapolar grid (``rings`` rings per wavelength).

    Keys: rms_um (centroid-referenced, weighted over wavelengths), rms_um_per_wavelength,
    centroid_x_mm, centroid_y_mm, chief_y_mm, n_rays, n_ok, vignetting (transmitted
    fraction of the pupil), relative_illumination (image irradiance relative to axis).
    """

def field_fold(
    lens_json: str, field_max_deg: float, wavelength_nm: float | None = None, aiming: str = "paraxial"
) -> dict[str, float] | None:
    """Where the image of the field folds between the axis and ``field_max_deg`` (a pupil point
    whose meridional image height stops growing with the field; 15 x 15 pupil grid, 41 fields):
    {field_deg, px, py, step_mm} of the worst step, None when the mapping is one-to-one."""

def chief_ray_status(
    lens_json: str, fields_deg: list[float], wavelengths_nm: list[float], aiming: str = "paraxial"
) -> list[int | str]:
    """The chief ray's status code (0 ok, 1 missed, 2 clipped, 3 TIR, 4 invalid) at each field
    and wavelength, fields outer; the engine's message where its beam cannot be launched."""

def ray_footprint(
    lens_json: str,
    n_surfaces: int,
    fields_deg: list[float],
    wavelengths_nm: list[float],
    px: NDArray[np.float64],
    py_: NDArray[np.float64],
    aiming: str = "paraxial",
) -> NDArray[np.float64]:
    """(n_surfaces,) largest radial height at each surface of the pupil rays (px, py) of every
    field and wavelength that reach the image (0 where none does); the first error raised."""

def psf(
    lens_json: str,
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
    progress: Callable[[int, int], None] | None = None,
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Monochromatic PSF with method "geometric", "fft", "huygens" or "auto".

    ``progress(done, total)``: the computation runs on a thread of its own while the caller's
    thread calls it every 0.2 s and checks for Ctrl-C (an interrupt stops the computation and
    is re-raised).

    "auto": the cheapest method and sampling predicted to meet ``accuracy`` (relative L1
    error against the converged Huygens PSF) for this lens, field and wavelength
    (crates/psf-engine/src/psf/auto.rs); ``pupil_samples`` and ``fast`` are then chosen,
    and the diagnostics hold ``requested_method`` = "auto" and ``auto`` (the choice, its
    predicted error and cost, the probe's measurements; a warning if nothing is predicted
    to meet the target).

    Diagnostics keys: method, strehl, warnings (list[str]), time_s, chief_x_mm,
    chief_y_mm, transmitted_fraction, energy_in_window, pupil_samples, and the
    method's sampling checks (max_phase_step_waves, native_pitch_x_um, ...).
    ``integrate=False`` gives intensity at pixel centres x pixel area (a super-resolved
    PSF); ``True`` integrates over each pixel (what a detector pixel collects; geometric
    always integrates). ``exact`` makes Huygens evaluate every distance exactly.
    ``pupil_samples`` is also the ray grid across the pupil for the geometric method, whose
    cells are split into sub-points interpolated from the traced rays (no ray noise;
    docs/accuracy.md, "Spots larger than the window").

    ``fast=True`` (method "fft"): the fast FFT path of :func:`psf_batch` (see there) where
    it applies, else the general FFT; diagnostics ``fft_mode`` ("direction_grid" or
    "general") and, after a fallback, ``fast_fallback`` (the reason).
    """

def psf_rgb(
    lens_json: str,
    field_deg: float,
    channels: Sequence[Sequence[tuple[float, float]]],
    method: str = "fft",
    pixel_um: float = 1.0,
    size: int = 64,
    pupil_samples: int = 64,
    aiming: str = "paraxial",
    integrate: bool = False,
    fast: bool = True,
    accuracy: float = 0.02,
) -> tuple[NDArray[np.float64], NDArray[np.float64], dict[str, Any]]:
    """Per-channel PSF (C, size, size), each normalized to unit sum, and the per-channel
    relative illumination (C,). ``channels[c]`` lists (wavelength_nm, weight) pairs.
    ``fast`` as in :func:`psf_batch` (the same computation, so the two agree)."""

def auto_candidates(
    lens_json: str,
    field_deg: float,
    wavelength_nm: float,
    pixel_um: float = 1.0,
    size: int = 64,
    aiming: str = "paraxial",
    integrate: bool = False,
) -> dict[str, Any]:
    """What method "auto" sees: ``probe`` (its measurements) and ``candidates`` (name,
    method, fast, pupil_samples, predicted_rel_l1, predicted_cost_s; cheapest first)."""

def psf_set_vjp(
    lens_json: str,
    fields_deg: Sequence[float],
    channels: Sequence[Sequence[tuple[float, float]]],
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
    """The one-pass gradient of one design's PSF set (GIL released): dL/d(params) from
    ``g_psf`` = dL/dPSF, float64 [fields, channels, m, m] (m = sensor[1] where ``sensor`` =
    (pitch_um, m) bins the PSFs to sensor pixels, else ``size``) and ``g_ri`` = dL/d(relative
    illumination) [fields, channels], for the set ``psf_batch`` computes with the same options
    (each channel normalized to unit sum). ``params``: (kind, surface from 0, aspheric term
    index from 0 = r^2) with kind curvature, radius, conic, aspheric, thickness, f_number or
    epd (surface and index ignored where they do not apply). ``focus`` = (fields_deg,
    (nm, weight) pairs, rings): the image plane follows the best focus (best_focus_batch's),
    so its shift's tangent enters; None: the image plane is held. Returns grad (P,) float64,
    psf [fields, channels, size, size] and relative_illumination [fields, channels] (the set's,
    before binning), and fallback: None, or why this design has no one-pass gradient (the
    first PSF not from the fast FFT with fitted pupils, real-ray aiming, a curved image); then
    grad, psf and relative_illumination are None and the caller uses differences.
    """

def best_focus_batch(
    lens_jsons: Sequence[str],
    fields_deg: Sequence[float],
    wavelengths: Sequence[tuple[float, float]],
    rings: int = 8,
    aiming: str = "paraxial",
) -> dict[str, Any]:
    """Best focus of many designs (parallel, GIL released): the image-plane shift (mm,
    positive = away from the lens) minimizing the mean over ``fields_deg`` of the
    polychromatic centroid RMS spot squared, closed-form from one trace per field and
    wavelength (``wavelengths``: (nm, weight) pairs; polar pupil grid of ``rings`` rings).
    Returns shift_mm (D,) float64, ok (D,) bool, errors (list[str | None]); a failed
    design has shift 0.
    """

def crc32(data: NDArray[np.uint8], crc: int = 0) -> int:
    """CRC-32 (IEEE, the same as ``zlib.crc32``) of a contiguous byte array, continuing
    from ``crc``; GIL released (crc32fast, ~10 GB/s)."""

def psf_batch(
    lens_jsons: Sequence[str],
    fields_deg: Sequence[float],
    channels: Sequence[Sequence[tuple[float, float]]],
    method: str = "fft",
    pixel_um: float = 1.0,
    size: int = 64,
    pupil_samples: int = 64,
    aiming: str = "paraxial",
    integrate: bool = False,
    fast: bool = True,
    out: NDArray[np.float32] | None = None,
    sensor: tuple[float, int] | None = None,
    sensor_out: NDArray[np.float32] | None = None,
    accuracy: float = 0.02,
) -> dict[str, Any]:
    """Many designs x fields x channels in one call (GIL released, parallel over
    design x field, each PSF single threaded; the output does not depend on the number
    of threads).  ``out``: a C-contiguous float32 array (D, F, C, size, size) to write the
    PSFs into (every value overwritten; returned as ``psf``), e.g. a reused buffer.
    ``sensor=(pitch_um, m)``: also each PSF integrated over m x m sensor pixels of that
    pitch (fine and sensor grids centred on pixel size // 2; each fine pixel a box of one
    pitch, weighted by its area inside a sensor pixel), binned from the double-precision
    PSF, returned as ``psf_sensor`` (D, F, C, m, m) float32, into ``sensor_out`` if given.

    Returns psf (D, F, C, size, size) float32 (unit sum per channel),
    relative_illumination (D, F, C) float64, energy_in_window (D, F, C) float64 (the
    fraction of the transmitted energy inside the window, the channel's wavelengths
    weighted), warnings (list per design of the PSFs' warnings, each prefixed "field F deg,
    W nm: "), ok (D,) bool, errors (list[str | None]) with the reason a design failed (its
    PSFs are zeros and ok is False).

    ``fast=True`` (default; method "fft" with paraxial aiming and point sampling): the
    pupil function is fitted from ~80 traced rays (half the pupil and its rim; Legendre
    polynomials, the lowest degree of 8, 10, 12 whose residual is <= 1e-3 waves) and
    resampled onto a grid of image-space direction cosines whose FFT lands directly on
    the output pixels (FFT field >= 2 x the window and >= 4 x the geometric spot, no
    Taylor series, no resampling, anti-aliased pupil edge), each PSF single threaded;
    ``pupil_samples`` is then the least number of grid cells across the pupil. Relative L1 error <= 1% against a 256-sample
    general FFT on the bundled paper-triplet (tested). Where it does not apply (vignetting
    or TIR in its ray set, a fit out of tolerance, Real aiming, integrate=True) the
    general FFT runs, with ``pupil_samples`` rays across the pupil. ``fast=False``: the
    general FFT everywhere.

    Relative illumination: the image irradiance at the chief ray's image point over that
    on the axis, for a uniform object at infinity: the flux through the real pupil per unit
    image area (each pupil point's etendue over the Jacobian of its landing point with
    respect to the object direction; a Gauss grid of 24 half-pupil points where every ray passes, 24 rings
    where vignetting cuts the pupil). It holds at any image-plane position (refocused
    designs included). A design whose value leaves [0, 1.05] fails with the reason, and so
    does one with a PSF whose window holds more than 1.01 times the transmitted energy
    (method auto escalates to a more accurate candidate first) or with no energy in a PSF.
    """

def predicted_psf_seconds(
    method: str,
    pixel_um: float,
    size: int,
    pupil_samples: int,
    fft_grid: int | None = None,
    n_surfaces: int = 10,
) -> float | None:
    """Single-thread seconds the engine's cost model predicts for one PSF (None for "auto")."""

def available_memory() -> float:
    """Memory available for new allocations (bytes), as the engine's size checks see it."""
