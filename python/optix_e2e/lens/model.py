"""The :class:`Lens` object: a validated, material-resolved prescription plus thin
wrappers around the Rust engine (:mod:`optix_e2e.engine`)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .. import engine
from ..errors import InputError
from ..io import write_text_atomic
from .prescription import PrescriptionError, SurfacesCrossError, resolve_prescription, tree_copy
from .pupil import pupil_quadrature
from .text import display_name

__all__ = ["Lens", "LensLoadError", "bundled_lenses", "DEFAULT_RGB_CHANNELS"]

BUNDLED_DIR = Path(__file__).resolve().parent.parent / "bundled"
#: Bundled lens name -> its shipped surrogate checkpoint in BUNDLED_DIR (optix_e2e.surrogate).
BUNDLED_SURROGATES = {
    "paper-triplet-v1": "surrogate_paper_triplet.pt",
    "paper-triplet-e2e": "surrogate_paper_triplet_e2e.pt",  # the space, not a lens
    "paper-triplet-detect": "surrogate_paper_triplet_detect.pt",  # e2e + the f-number
    "apo-gauss-8e-mv": "surrogate_apo_gauss_8e_mv.pt",
}  # the eight-element experiment

#: Default sensor channels (R, G, B): three wavelengths each, weights ~ a smooth
#: spectral response.  Used when a lens does not list exactly three wavelengths or when
#: asked for explicitly.
DEFAULT_RGB_CHANNELS: list[list[tuple[float, float]]] = [
    [(600.0, 0.25), (625.0, 0.5), (650.0, 0.25)],
    [(520.0, 0.25), (550.0, 0.5), (580.0, 0.25)],
    [(450.0, 0.25), (475.0, 0.5), (500.0, 0.25)],
]


class LensLoadError(PrescriptionError):
    """A lens that cannot be loaded: missing file, bad JSON, unknown bundled name."""


def bundled_lenses() -> list[str]:
    """Names of the lenses shipped with the package (``optix_e2e/bundled/*.json``)."""
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.json"))


def _surfaces_crossing_in_beam(data: dict) -> str | None:
    """Two consecutive surfaces that cross inside the beam, where either lacks a clear
    semi-diameter (the engine checks the edges of given apertures itself): the beam's
    radius at each surface is the paraxial marginal plus chief ray height at full field
    (a lower bound of the real footprint). None when they do not, or when the paraxial
    trace itself fails (the engine then names the problem)."""
    from .surface import curvature, sag

    surfs = data["surfaces"]
    if all(s.get("semi_diameter") is not None for s in surfs):
        return None
    js = json.dumps(data)
    try:
        par = engine.paraxial(js)
        n = engine.refractive_indices(js, wavelength_nm=par["wavelength_nm"])
    except Exception:  # the engine's own checks report it when the lens is used
        return None
    u_chief = math.tan(math.radians(max(abs(f) for f in data["fields_deg"])))
    h = 0.5 * par["epd_mm"]
    marginal = [h, 0.0]
    if math.isfinite(par["object_to_pupil_mm"]):  # from the axial object point to the pupil's rim
        L = par["object_to_pupil_mm"]
        marginal = [h * (L - par["entrance_pupil_z_mm"]) / L, h / L]
    rays = [marginal, [-par["entrance_pupil_z_mm"] * u_chief, u_chief]]  # (y, n u)
    heights = []
    for i, s in enumerate(surfs):
        heights.append(sum(abs(y) for y, _ in rays))
        for ray in rays:
            ray[1] -= ray[0] * curvature(s) * (n[i + 1] - n[i])
            ray[0] += ray[1] / n[i + 1] * float(s["thickness"])
    for i in range(len(surfs) - 1):
        a, b = surfs[i], surfs[i + 1]
        if a.get("semi_diameter") is not None and b.get("semi_diameter") is not None:
            continue
        ha = a.get("semi_diameter") or heights[i]
        hb = b.get("semi_diameter") or heights[i + 1]
        r = np.linspace(0.0, min(ha, hb), 17)[1:]
        with np.errstate(invalid="ignore"):
            gap = float(a["thickness"]) + sag(b, r) - sag(a, r)
        j = np.flatnonzero(gap < -1e-9)
        if len(j):
            k = int(j[0])
            return (
                f"surfaces {i + 1} and {i + 2} cross at height {r[k]:.3g} mm, inside the beam (thickness "
                f"{float(a['thickness']):g} mm leaves a gap of {gap[k]:.3g} mm there; the beam's paraxial "
                f"radius is {min(ha, hb):.3g} mm)"
            )
    return None


class Lens:
    """A lens prescription (docs/lens-format.md) with its materials resolved.

    Build one with :meth:`load` (path, bundled name, dict or Lens) or directly from a
    dict.  ``source`` names where it came from in error messages.
    """

    def __init__(self, data: dict, source: str = "<dict>"):
        self.source = source
        self.data = resolve_prescription(data, source)
        crossing = _surfaces_crossing_in_beam(self.data)
        if crossing:
            raise SurfacesCrossError(f"{source}: {crossing}")
        #: the prescription as given (catalog names unresolved): what save() writes
        self.raw = tree_copy(data)
        #: for a lens read from .zmx: the :class:`optix_e2e.lens.zemax.ZemaxImport` report
        self.zemax_import = None
        self._json: str | None = None

    # ----- loading -------------------------------------------------------------
    @classmethod
    def load(cls, spec: "str | Path | dict | Lens") -> "Lens":
        if isinstance(spec, Lens):
            return spec
        if isinstance(spec, dict):
            return cls(spec)
        path = Path(spec)
        if path.is_file():
            return cls.from_file(path)
        if isinstance(spec, str) and spec in bundled_lenses():
            return cls.from_file(BUNDLED_DIR / f"{spec}.json", source=f"bundled lens {spec!r}")
        if path.suffix.lower() in (".json", ".zmx") or path.parent != Path("."):
            raise LensLoadError(f"{spec}: no such lens file")
        raise LensLoadError(
            f"{spec!r} is neither a lens file nor a bundled lens (bundled: {', '.join(bundled_lenses())})"
        )

    @classmethod
    def from_file(cls, path: "str | Path", source: str | None = None, *, strict: bool = True) -> "Lens":
        """A JSON prescription, or a Zemax .zmx file (by extension; ``strict=False``
        lists unknown .zmx keywords as ignored instead of failing, see docs/zemax.md)."""
        path = Path(path)
        if path.suffix.lower() == ".zmx":
            from .zemax import read_zmx

            imp = read_zmx(path, strict=strict)
            lens = cls(imp.data, source=source or str(path))
            lens.zemax_import = imp
            return lens
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise LensLoadError(f"{path}: cannot read lens file ({exc.strerror or exc})") from exc
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = raw.count(b"\n", 0, exc.start) + 1
            col = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
            raise LensLoadError(
                f"{path}:{line}:{col}: not UTF-8 text (byte 0x{raw[exc.start]:02x}); save the lens file as UTF-8"
            ) from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise LensLoadError(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON: {exc.msg}") from exc
        except RecursionError:
            raise LensLoadError(f"{path}: invalid JSON: nested too deeply to be a lens prescription") from None
        data.setdefault("name", display_name(path.stem)) if isinstance(data, dict) else None
        return cls(data, source=source or str(path))

    # ----- saving -----------------------------------------------------------------
    def zmx_footprint(self, n_rim: int = 32) -> list[float]:
        """The automatic semi-diameters written to .zmx files (OpticStudio's: the largest
        height of the pupil rim and chief rays of every field and wavelength) on each surface
        and the image; 0 where no ray gets there. A reader that clips at semi-diameters (ours
        does, docs/zemax.md) must then clip none of the light the lens passes: each height is
        raised by 1 %, so rays at wavelengths between and a little beyond the lens's own pass
        too (OpticStudio's automatic value has no margin; it does not clip)."""
        import numpy as np

        t = np.linspace(0.0, 2 * np.pi, n_rim, endpoint=False)
        try:
            h = engine.ray_footprint(
                self.to_engine_json(),
                n_surfaces=len(self.surfaces) + 1,
                fields_deg=self.fields_deg,
                wavelengths_nm=self.wavelengths_nm,
                px=np.append(np.sin(t), 0.0),
                py=np.append(np.cos(t), 0.0),
            )
        except Exception:  # noqa: BLE001 - a lens the engine cannot trace (afocal, say) still exports
            return [0.0] * (len(self.surfaces) + 1)  # DIAM 0: automatic, size unknown
        return [float(v) * 1.01 for v in h]

    def to_zmx(self) -> str:
        """The prescription as Zemax .zmx text (docs/zemax.md)."""
        from .zemax import zmx_text

        return zmx_text(self.raw, self.source, self.zmx_footprint())

    def save(self, path: "str | Path", *, encoding: str = "utf-8") -> Path:
        """Write the prescription as ``.json`` or ``.zmx`` (by extension); ``encoding``
        ("utf-8" or "utf-16", OpticStudio's own) applies to .zmx."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".zmx":
            from .zemax import write_zmx

            return write_zmx(self.raw, path, encoding=encoding, source=self.source, footprint=self.zmx_footprint())
        if suffix == ".json":
            write_text_atomic(path, json.dumps(self.raw, indent=2) + "\n")
            return path
        raise LensLoadError(f"{path}: unknown lens file extension {path.suffix!r} (use .json or .zmx)")

    # ----- prescription data ------------------------------------------------------
    @property
    def name(self) -> str:
        return self.data.get("name", "lens")

    @property
    def wavelengths_nm(self) -> list[float]:
        return [float(w) for w in self.data["wavelengths_nm"]]

    @property
    def wavelength_weights(self) -> list[float]:
        w = self.data.get("wavelength_weights")
        return [float(x) for x in w] if w else [1.0] * len(self.wavelengths_nm)

    @property
    def primary_wavelength_nm(self) -> float:
        if "primary_wavelength_nm" in self.data:
            return float(self.data["primary_wavelength_nm"])
        wls = self.wavelengths_nm
        return wls[len(wls) // 2]

    @property
    def fields_deg(self) -> list[float]:
        return [float(f) for f in self.data["fields_deg"]]

    @property
    def object_distance(self) -> float:
        """Object plane to the first surface (mm); ``inf`` for an object at infinity."""
        d = self.data.get("object_distance")
        return math.inf if d is None or isinstance(d, str) else float(d)

    @property
    def max_field_deg(self) -> float:
        return max(self.fields_deg)

    @property
    def surfaces(self) -> list[dict]:
        return self.data["surfaces"]

    def rgb_channels(self, mode: str = "rgb") -> list[list[tuple[float, float]]]:
        """Channels for :meth:`psf_rgb`: ``"lens"`` maps exactly three lens wavelengths
        (longest first) to R, G, B; ``"rgb"`` uses :data:`DEFAULT_RGB_CHANNELS`."""
        if mode == "lens":
            pairs = sorted(zip(self.wavelengths_nm, self.wavelength_weights), reverse=True)
            if len(pairs) != 3:
                raise PrescriptionError(
                    f"{self.source}: channel mode 'lens' needs exactly 3 wavelengths, lens has {len(pairs)}"
                )
            return [[p] for p in pairs]
        if mode == "rgb":
            return [list(c) for c in DEFAULT_RGB_CHANNELS]
        raise InputError(f"unknown channel mode {mode!r} (lens or rgb)")

    def to_engine_json(self) -> str:
        """The resolved prescription as the JSON string the engine takes."""
        if self._json is None:
            self._json = json.dumps(self.data)
        return self._json

    def _engine_call(self, fn, **kwargs):
        """The engine function ``fn`` (optix_e2e.engine) on this lens; an engine error names the
        lens's source (its file) before the engine's own words (surface, parameter)."""
        try:
            return fn(self.to_engine_json(), **kwargs)
        except engine.EngineError as exc:
            if str(exc).startswith(str(self.source)):
                raise
            raise type(exc)(f"{self.source}: {exc}") from None

    def __repr__(self) -> str:
        return f"Lens({self.name!r}, {len(self.surfaces)} surfaces, source={self.source!r})"

    # ----- engine wrappers --------------------------------------------------------
    def validate(self) -> None:
        self._engine_call(engine.validate_lens)

    def refractive_indices(self, wavelength_nm: float | None = None) -> np.ndarray:
        wl = self.primary_wavelength_nm if wavelength_nm is None else wavelength_nm
        return self._engine_call(engine.refractive_indices, wavelength_nm=wl)

    def paraxial(self, wavelength_nm: float | None = None) -> dict[str, float]:
        return self._engine_call(engine.paraxial, wavelength_nm=wavelength_nm)

    def trace_field(
        self, field_deg: float, px, py, wavelength_nm: float | None = None, aiming: str = "paraxial"
    ) -> dict[str, np.ndarray]:
        wl = self.primary_wavelength_nm if wavelength_nm is None else wavelength_nm
        return self._engine_call(engine.trace_field, field_deg=field_deg, px=px, py=py, wavelength_nm=wl, aiming=aiming)

    def spot(
        self,
        field_deg: float,
        wavelengths_nm: Sequence[float] | None = None,
        weights: Sequence[float] | None = None,
        rings: int = 64,
        aiming: str = "paraxial",
    ) -> dict[str, Any]:
        """Spot statistics; by default polychromatic over the lens's wavelengths and weights."""
        if wavelengths_nm is None:
            wavelengths_nm = self.wavelengths_nm
            weights = self.wavelength_weights if weights is None else weights
        return self._engine_call(
            engine.spot, field_deg=field_deg, wavelengths_nm=wavelengths_nm, weights=weights, rings=rings, aiming=aiming
        )

    def field_fold(self, field_max_deg: float | None = None, aiming: str = "paraxial") -> dict | None:
        """Where the image of the field folds between the axis and ``field_max_deg`` (default:
        the lens's largest field): a pupil point whose image height stops growing with the
        field (engine spot::field_fold), None when the mapping is one-to-one. The engine
        refuses the relative illumination and RGB PSFs of a lens that folds."""
        f = self.max_field_deg if field_max_deg is None else field_max_deg
        return self._engine_call(engine.field_fold, field_max_deg=f, aiming=aiming)

    def wavefront(
        self, field_deg: float, rings: int = 8, arms: int = 16, tilt: str = "wavelength", aiming: str = "paraxial"
    ) -> dict[str, Any]:
        """RMS wavefront error (waves) of a field over the lens's wavelengths: OPD against the
        chief ray's reference sphere, piston removed per wavelength, tilt per wavelength
        (Zemax's centroid reference) or per field; a Gaussian quadrature of ``rings`` x
        ``arms`` pupil points.  Keys of ``engine.wavefront`` plus ``rms_waves_poly``, the
        wavelength-weighted quadratic mean."""
        px, py, pw = pupil_quadrature(rings, arms)
        ww = np.asarray(self.wavelength_weights, float)
        out = self._engine_call(
            engine.wavefront,
            field_deg=field_deg,
            px=px,
            py=py,
            weights=pw,
            wavelengths_nm=self.wavelengths_nm,
            wavelength_weights=ww,
            aiming=aiming,
            tilt=tilt,
        )
        out["rms_waves_poly"] = float(np.sqrt(np.sum(ww * np.asarray(out["rms_waves"]) ** 2) / ww.sum()))
        return out

    def petzval(self, wavelength_nm: float | None = None) -> dict[str, float]:
        """Petzval sum P = sum over surfaces of (n' - n) / (n n' R) (1/mm) and the Petzval
        radius -1 / (n'_image P) of the image surface a flat-field design must bend back."""
        from .surface import curvature

        n = self.refractive_indices(wavelength_nm)
        total = 0.0
        for i, surf in enumerate(self.surfaces):
            # paraxial curvature: an r^2 aspheric term adds 2 a2
            c = curvature(surf) + 2.0 * float((surf.get("aspheric") or {}).get("a2", 0.0))
            total += (n[i + 1] - n[i]) * c / (n[i] * n[i + 1])
        return {"petzval_sum_per_mm": total, "petzval_radius_mm": -1.0 / (n[-1] * total) if total != 0 else math.inf}

    def psf(
        self, field_deg: float, wavelength_nm: float | None = None, method: str = "fft", **kwargs
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Monochromatic PSF; keyword arguments as :func:`optix_e2e.engine.psf`.  ``method``
        "auto" picks the cheapest method and sampling predicted to meet
        ``accuracy`` (relative L1, default 0.02) and records its choice under ``"auto"``."""
        wl = self.primary_wavelength_nm if wavelength_nm is None else wavelength_nm
        return self._engine_call(engine.psf, field_deg=field_deg, wavelength_nm=wl, method=method, **kwargs)

    def psf_rgb(self, field_deg: float, channels=None, method: str = "fft", **kwargs):
        """Per-channel PSFs (C, size, size) and relative illumination (C,); channels default
        to :meth:`rgb_channels` ("rgb")."""
        channels = self.rgb_channels("rgb") if channels is None else channels
        channels = [[(float(w), float(k)) for w, k in ch] for ch in channels]
        return self._engine_call(engine.psf_rgb, field_deg=field_deg, channels=channels, method=method, **kwargs)
