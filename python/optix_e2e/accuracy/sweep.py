"""The measurements behind ``optix bench accuracy``: every method and setting against the
converged reference at each lens, field and wavelength; wavelengths per colour channel
against a dense spectral sum; field samples K with interpolation against every field.

Each row of the result is one measurement: its cost (wall time, median of repeats; rays
traced, ray-surface intersections, FFT points, Huygens wavelet terms) and its errors
(relative L1 and L2 of the PSF, Strehl error, 80% encircled-energy radius error, relative
L2 error of a test image rendered through it)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..lens import Lens
from .psf_errors import ee_radius, rel_l1, rel_l2, render_error, scene_chart
from .reference import converged_reference


@dataclass(frozen=True)
class Setting:
    method: str  # geometric | fft | fft-fast | huygens
    pupil_samples: int
    pad: int | None = None  # FFT grid = pad x pupil_samples (None: the engine's default)

    @property
    def name(self) -> str:
        s = f"{self.method} N={self.pupil_samples}"
        return s + (f" Q={self.pad}" if self.pad else "")


def method_settings(quick: bool = False) -> list[Setting]:
    """The grid of methods and settings swept at every case."""
    ns = (16, 32, 64) if quick else (16, 32, 64, 128)
    out = [Setting("geometric", n) for n in ((16, 64, 256) if quick else (16, 32, 64, 128, 256, 512))]
    out += [Setting("fft", n, q) for n in ns for q in (2, 4, 8)]
    out += [Setting("fft", n) for n in ns]
    out += [Setting("fft-fast", n) for n in ns]
    out += [Setting("huygens", n) for n in ((16, 32, 64) if quick else (16, 32, 64, 128, 256))]
    return out


@dataclass
class Config:
    size: int = 128
    pixel_um: float = 1.0
    repeats: int = 3  # timed calls per setting (median), after one warm-up
    max_repeat_s: float = 0.5  # fewer repeats where one call takes longer
    ref_start: int = 128
    ref_tol: float = 5e-3
    ref_max: int = 1024
    wavelengths_per_channel: tuple = (1, 3, 5, 9)
    spectral_reference: int = 33
    k_fields: tuple = (2, 3, 4, 5, 7, 9, 13)
    dense_fields: int = 21
    chart: np.ndarray = field(default_factory=lambda: scene_chart(192))


def timed(fn, repeats: int, max_s: float = float("inf")):
    """(result of the last call, median seconds) over up to ``repeats`` calls after a
    warm-up, stopping early once ``max_s`` seconds are spent."""
    res = fn()
    times = []
    spent = 0.0
    while len(times) < repeats and (not times or spent < max_s):
        t = time.perf_counter()
        res = fn()
        dt = time.perf_counter() - t
        times.append(dt)
        spent += dt
    return res, float(np.median(times))


def _engine_psf(js: str, f: float, wl: float, s: Setting, cfg: Config):
    from .. import engine

    method = "fft" if s.method == "fft-fast" else s.method
    grid = s.pad * s.pupil_samples if s.pad else None
    return engine.psf(
        js,
        field_deg=f,
        wavelength_nm=wl,
        method=method,
        pixel_um=cfg.pixel_um,
        size=cfg.size,
        pupil_samples=s.pupil_samples,
        fft_grid=grid,
        fast=s.method == "fft-fast",
    )


def _costs(s: Setting, diag: dict, n_surfaces: int, size: int) -> dict:
    """Work counts: rays launched inside the pupil, intersections (rays x surfaces and the
    image plane), FFT points (grid^2), Huygens wavelet terms (rays x output pixels)."""
    if s.method == "fft-fast":
        rays = int(diag.get("rays_traced", 0))
    else:
        rays = int(round(math.pi / 4 * s.pupil_samples**2))
    g = diag.get("fft_grid")
    return {
        "rays": rays,
        "intersections": rays * (n_surfaces + 1),
        "fft_points": int(g) ** 2 if g and s.method in ("fft", "fft-fast") else 0,
        "wavelet_terms": rays * size * size if s.method == "huygens" else 0,
    }


def _errors(psf: np.ndarray, ref: np.ndarray, cfg: Config, strehl=None, strehl_ref=None) -> dict:
    centre = _centroid(ref)
    ee, ee_ref = ee_radius(psf, cfg.pixel_um, 0.8, centre), ee_radius(ref, cfg.pixel_um, 0.8, centre)
    s_err = abs(strehl - strehl_ref) if strehl is not None and strehl_ref is not None else float("nan")
    return {
        "rel_l1": rel_l1(psf, ref),
        "rel_l2": rel_l2(psf, ref),
        "strehl": strehl if strehl is not None else float("nan"),
        "strehl_ref": strehl_ref if strehl_ref is not None else float("nan"),
        "strehl_err": s_err,
        "ee80_um": ee,
        "ee80_ref_um": ee_ref,
        "ee80_err_um": abs(ee - ee_ref),
        "image_rel_l2": render_error(psf, ref, cfg.chart),
    }


def _centroid(p: np.ndarray) -> tuple[float, float]:
    r, c = np.indices(p.shape)
    t = p.sum()
    return float((r * p).sum() / t), float((c * p).sum() / t)


def method_rows(lens: Lens, field_deg: float, wavelength_nm: float, settings: list[Setting], cfg: Config) -> list[dict]:
    """Every setting at one lens, field and wavelength, against the converged reference."""
    js = lens.to_engine_json()
    ref = converged_reference(
        js,
        field_deg,
        wavelength_nm,
        size=cfg.size,
        pixel_um=cfg.pixel_um,
        start=cfg.ref_start,
        tol=cfg.ref_tol,
        max_samples=cfg.ref_max,
    )
    base = {
        "experiment": "method",
        "lens": lens.name,
        "field_deg": field_deg,
        "wavelength_nm": wavelength_nm,
        "reference_samples": ref.pupil_samples,
        "reference_convergence": ref.convergence,
        "reference_energy_in_window": float(ref.psf.sum()),
    }
    rows = []
    for s in settings:
        row = {**base, "method": s.method, "setting": s.name, "pupil_samples": s.pupil_samples, "pad": s.pad or ""}
        try:
            (psf, diag), dt = timed(
                lambda: _engine_psf(js, field_deg, wavelength_nm, s, cfg), cfg.repeats, cfg.max_repeat_s
            )
        except Exception as exc:  # an engine refusal is a result too
            rows.append({**row, "error": f"{type(exc).__name__}: {exc}"})
            continue
        row.update(
            time_s=dt,
            **_costs(s, diag, len(lens.surfaces), cfg.size),
            **_errors(psf, ref.psf, cfg, diag.get("strehl"), ref.strehl),
            n_warnings=len(diag.get("warnings", [])),
            warnings=" | ".join(diag.get("warnings", [])),
            fft_mode=diag.get("fft_mode", ""),
        )
        rows.append(row)
    return rows


#: Sensor channel responses for the spectral experiment: Gaussians (centre, sigma nm),
#: each cut at +-2 sigma (IMX249-like peaks; blue kept above 436.8 nm, where the PMMA
#: dispersion formula starts).
CHANNEL_RESPONSE = {"R": (610.0, 30.0), "G": (540.0, 30.0), "B": (480.0, 20.0)}


def channel_wavelengths(name: str, k: int) -> list[tuple[float, float]]:
    """k (wavelength, weight) pairs for channel ``name``: the +-2 sigma band split into k
    equal parts, each represented by its middle wavelength and weighted by the response
    integrated over it (the midpoint rule on the band: k = 1 is the centre wavelength)."""
    c, sig = CHANNEL_RESPONSE[name]
    edges = np.linspace(c - 2 * sig, c + 2 * sig, k + 1)
    from math import erf, sqrt

    cdf = [0.5 * (1 + erf((e - c) / (sig * sqrt(2)))) for e in edges]
    w = np.diff(cdf)
    return [(float(0.5 * (a + b)), float(x / w.sum())) for a, b, x in zip(edges[:-1], edges[1:], w)]


def spectral_rows(lens: Lens, field_deg: float, cfg: Config) -> list[dict]:
    """Each channel's PSF from 1, 3, 5, 9 wavelengths against ``cfg.spectral_reference``
    wavelengths (fast FFT, 64 pupil samples; each channel normalized to unit sum)."""
    from .. import engine

    js = lens.to_engine_json()
    rows = []

    def run(ch):
        p, ri, _ = engine.psf_rgb(
            js,
            field_deg=field_deg,
            channels=[ch],
            method="fft",
            pixel_um=cfg.pixel_um,
            size=cfg.size,
            pupil_samples=64,
            fast=True,
        )
        return p[0]

    for name in CHANNEL_RESPONSE:
        ref = run(channel_wavelengths(name, cfg.spectral_reference))
        for k in cfg.wavelengths_per_channel:
            psf, dt = timed(lambda: run(channel_wavelengths(name, k)), cfg.repeats, cfg.max_repeat_s)
            err = _errors(psf, ref, cfg)
            rows.append(
                {
                    "experiment": "spectral",
                    "lens": lens.name,
                    "field_deg": field_deg,
                    "channel": name,
                    "method": "fft-fast",
                    "setting": f"{k} wavelengths",
                    "n_wavelengths": k,
                    "time_s": dt,
                    "reference_wavelengths": cfg.spectral_reference,
                    **err,
                }
            )
    return rows


def field_rows(lens: Lens, wavelength_nm: float, cfg: Config) -> list[dict]:
    """PSFs at ``cfg.dense_fields`` fields from K uniformly spaced samples, linearly
    interpolated in field angle (the PSFs are centred on the chief ray), against the PSF
    computed at each field (fast FFT, 64 pupil samples); error = the mean over the fields."""
    from .. import engine

    js = lens.to_engine_json()
    fmax = lens.max_field_deg
    dense = np.linspace(0.0, fmax, cfg.dense_fields)

    def one(f):
        return engine.psf(
            js,
            field_deg=f,
            wavelength_nm=wavelength_nm,
            method="fft",
            pixel_um=cfg.pixel_um,
            size=cfg.size,
            pupil_samples=64,
            fast=True,
        )[0]

    exact = [one(f) for f in dense]
    rows = []
    for k in cfg.k_fields:
        samples = np.linspace(0.0, fmax, k)
        psfs, dt = timed(lambda: [one(f) for f in samples], cfg.repeats, cfg.max_repeat_s)
        errs = []
        for f, ref in zip(dense, exact):
            i = min(int(np.searchsorted(samples, f, side="right")) - 1, k - 2)
            a = (f - samples[i]) / (samples[i + 1] - samples[i])
            errs.append(_errors((1 - a) * psfs[i] + a * psfs[i + 1], ref, cfg))
        mean = {key: _nanmean([e[key] for e in errs]) for key in errs[0]}
        rows.append(
            {
                "experiment": "fields",
                "lens": lens.name,
                "wavelength_nm": wavelength_nm,
                "method": "fft-fast",
                "setting": f"K={k}",
                "k_fields": k,
                "time_s": dt,
                "dense_fields": cfg.dense_fields,
                **mean,
                "rel_l1_max": float(max(e["rel_l1"] for e in errs)),
            }
        )
    return rows


def _nanmean(v) -> float:
    v = [x for x in v if x == x]
    return float(np.mean(v)) if v else float("nan")
