"""A lens's report (``optix lens report``): ``write_report`` writes layout.png, spots.png,
mtf.png and report.json from the analysis (:mod:`.analysis`) and the per-field MTF; the
figures are drawn in :mod:`.plots`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError
from ..io import write_record_atomic
from ..lens import Lens
from ..lens.mtf import NYQUIST_5P86_UM, default_frequencies, field_mtf, mtf_at, psf_sampling
from .analysis import spot_diagram

__all__ = ["write_report", "DEFAULT_MTF_FREQS"]

#: Frequencies (cycles/mm) whose MTF goes into report.json: round numbers and the
#: Nyquist frequency of a 5.86 um pixel.
DEFAULT_MTF_FREQS = (10.0, 20.0, 40.0, round(NYQUIST_5P86_UM, 2), 100.0)

Progress = Callable[[str], Any] | None


def write_report(
    lens: Lens,
    out_dir: str | Path,
    fields: Sequence[float] | None = None,
    aiming: str = "paraxial",
    rays: int = 9,
    freqs: Sequence[float] = DEFAULT_MTF_FREQS,
    max_freq: float | None = None,
    per_wavelength: bool = False,
    psf_method: str = "fft",
    progress: Progress = None,
) -> dict[str, Any]:
    """layout.png, spots.png, mtf.png and report.json in ``out_dir``; returns the JSON."""
    from . import plots as plotting

    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    out = Path(out_dir)
    fields = list(lens.fields_deg if fields is None else fields)
    par = lens.paraxial()
    # Check the MTF request before any work: 0 .. the grid's Nyquist frequency.
    samp = psf_sampling(lens, lens.wavelengths_nm)
    top = max_freq if max_freq is not None else default_frequencies(lens.wavelengths_nm, samp["f_number"])[-1]
    asked = [top, *freqs]
    if min(asked) < 0 or max(asked) > samp["grid_nyquist_cyc_mm"]:
        raise InputError(
            f"MTF frequencies must lie in 0..{samp['grid_nyquist_cyc_mm']:.1f} cycles/mm "
            f"(twice the diffraction cutoff), got {', '.join(f'{q:g}' for q in asked)}"
        )
    out.mkdir(parents=True, exist_ok=True)
    say("layout")
    plotting.save_layout_png(out / "layout.png", lens, fields=fields, rays=rays, aiming=aiming)
    spots = []
    for f in fields:
        say(f"spot diagram {f:g} deg")
        spots.append(spot_diagram(lens, f, aiming=aiming))
    plotting.save_spots_png(out / "spots.png", lens, spots)
    # One frequency grid for every field: 0 .. the cutoff (or max_freq), plus the
    # reported frequencies so that their values are exact, not interpolated.
    grid = np.union1d(np.linspace(0.0, top, 101), np.asarray(freqs, dtype=float))
    mtfs = []
    for f in fields:
        say(f"MTF {f:g} deg ({len(lens.wavelengths_nm)} {psf_method} PSFs)")
        mtfs.append(field_mtf(lens, f, grid, aiming=aiming, method=psf_method, progress=lambda m: say("  " + m)))
    plotting.save_mtf_png(
        out / "mtf.png", lens, mtfs, per_wavelength=per_wavelength, mark_freq=NYQUIST_5P86_UM, max_freq=top
    )
    rows = []
    for s, m in zip(spots, mtfs):
        rows.append(
            {
                "field_deg": s["field_deg"],
                "rms_spot_um": s["rms_um"],
                "rms_spot_um_per_wavelength": s["rms_um_per_wavelength"],
                "relative_illumination": s["relative_illumination"],
                "vignetting": s["vignetting"],
                "chief_y_mm": s["chief_y_mm"],
                "strehl_per_wavelength": m["strehl"],
                "mtf_psf_sampling": m["sampling_per_wavelength"],
                "mtf": {f"{q:g}": mtf_at(m, q) for q in freqs},
                "mtf_per_wavelength": {
                    f"{p['wavelength_nm']:g}": {
                        f"{q:g}": mtf_at({**p, "freq_cyc_mm": m["freq_cyc_mm"]}, q) for q in freqs
                    }
                    for p in m["per_wavelength"]
                },
                "mtf_curve": {
                    "freq_cyc_mm": m["freq_cyc_mm"],
                    "tangential": m["tangential"],
                    "sagittal": m["sagittal"],
                    "diffraction_limit": m["diffraction_limit"],
                },
                "warnings": m["warnings"],
            }
        )
    report = {
        "lens": lens.name,
        "source": lens.source,
        "aiming": aiming,
        "wavelengths_nm": lens.wavelengths_nm,
        "wavelength_weights": lens.wavelength_weights,
        "primary_wavelength_nm": lens.primary_wavelength_nm,
        "paraxial": par,
        "mtf_frequencies_cyc_mm": list(freqs),
        "mtf_method": f"{psf_method} PSF (point-sampled), OTF along x (sagittal) and y (tangential); "
        "polychromatic with lateral colour; diffraction limit at the working f-number",
        "mtf_sampling": mtfs[0]["sampling"] if mtfs else None,
        "fields": rows,
        "files": ["layout.png", "spots.png", "mtf.png", "report.json"],
        "time_s": time.perf_counter() - t0,
    }
    write_record_atomic(out / "report.json", report, indent=1)
    return report
