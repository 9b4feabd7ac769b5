"""``optix psf``: one monochromatic PSF to a .npy file, diagnostics as one JSON line."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ..errors import InputError
from ..io import save_npy_atomic
from ._common import AIMING, FiniteFloatRange, dumps, friendly_errors, load_lens


@click.command()
@click.argument("lens_spec", metavar="LENS")
@click.option(
    "--field-deg", type=FiniteFloatRange(-90.0, 90.0), default=0.0, show_default=True, help="Field angle along +y."
)
@click.option(
    "--wavelength-nm",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Default: the lens's primary wavelength.",
)
@click.option(
    "--method",
    type=click.Choice(["auto", "geometric", "fft", "huygens"]),
    default="auto",
    show_default=True,
    help="auto: the cheapest method and sampling predicted to meet --accuracy (recorded under 'auto').",
)
@click.option(
    "--accuracy",
    type=FiniteFloatRange(min=0, min_open=True),
    default=0.02,
    show_default=True,
    help="method auto: target relative L1 error of the PSF against the converged Huygens PSF.",
)
@click.option("--pixel-um", type=FiniteFloatRange(min=0, min_open=True), default=1.0, show_default=True)
@click.option(
    "--size", type=click.IntRange(2, 8192), default=64, show_default=True, help="Window is SIZE x SIZE pixels."
)
@click.option(
    "--pupil-samples",
    type=click.IntRange(4, 4096),
    default=64,
    show_default=True,
    help="Samples across the pupil (the ray grid for the geometric method).",
)
@click.option(
    "--fft-grid", type=click.IntRange(2, 1 << 20), default=None, help="FFT size (fft method; default: engine's choice)."
)
@click.option(
    "--integrate/--sample",
    default=False,
    show_default=True,
    help="Integrate over each pixel (what a detector pixel collects) or sample the intensity at "
    "pixel centres x pixel area (super-resolved PSF). Geometric PSFs always integrate.",
)
@click.option("--exact", is_flag=True, help="Huygens: evaluate every pupil-to-pixel distance exactly.")
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True)
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Output .npy file.")
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path), default=None, help="Also write a PNG image.")
@click.option("--log/--linear", "log", default=False, help="PNG intensity scale.")
@friendly_errors
def psf(
    lens_spec,
    field_deg,
    wavelength_nm,
    method,
    accuracy,
    pixel_um,
    size,
    pupil_samples,
    fft_grid,
    integrate,
    exact,
    aiming,
    out,
    png,
    log,
):
    """Compute the PSF of LENS at one field and wavelength and save it as .npy.

    The array's row index is image y, the column index image x, pixel (SIZE//2, SIZE//2)
    sits on the chief ray, and each pixel holds its fraction of the entrance-pupil flux.
    """
    if out.suffix.lower() != ".npy":  # numpy would append .npy to any other name
        raise InputError(f"--out {out}: the PSF array is written as .npy (name it *.npy; a picture: --png {out})")
    lens_ = load_lens(lens_spec)
    wl = lens_.primary_wavelength_nm if wavelength_nm is None else wavelength_nm
    kwargs = dict(pixel_um=pixel_um, size=size, pupil_samples=pupil_samples, aiming=aiming, accuracy=accuracy)
    if fft_grid is not None:
        kwargs["fft_grid"] = fft_grid
    if integrate:
        kwargs["integrate"] = True
    if exact:
        kwargs["exact"] = True
    image, diag = _with_estimate(
        lambda progress: lens_.psf(field_deg, wl, method, progress=progress, **kwargs),
        method,
        kwargs,
        len(lens_.surfaces),
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    save_npy_atomic(out, image)
    line = {
        "strehl": diag.get("strehl"),
        "time_s": diag.get("time_s"),
        "warnings": list(diag.get("warnings", [])),
        **diag,
        "requested_method": method,
        "lens": lens_.name,
        "field_deg": field_deg,
        "wavelength_nm": wl,
        "pixel_um": pixel_um,
        "size": size,
        "sum": float(np.sum(image)),
        "out": str(out),
    }
    if png is not None:
        from ..plotting import save_psf_png

        save_psf_png(png, image, pixel_um, title=f"{lens_.name} {method} {field_deg:g} deg {wl:g} nm", log=log)
        line["png"] = str(png)
    click.echo(dumps(line))


def _with_estimate(compute, method: str, kw: dict, n_surfaces: int):
    """Run ``compute(progress)``. Huygens over a large window says what the request is and
    shows the engine's progress (image rows or row blocks done; Ctrl-C stops it)."""
    if method != "huygens" or kw["size"] < 512:
        return compute(None)
    from tqdm import tqdm

    from .. import engine

    single = engine.predicted_psf_seconds(
        method=method,
        pixel_um=kw["pixel_um"],
        size=kw["size"],
        pupil_samples=kw["pupil_samples"],
        n_surfaces=n_surfaces,
    )
    click.echo(
        f"huygens: {kw['size']}x{kw['size']} pixels from about {0.785 * kw['pupil_samples'] ** 2:.0f} "
        f"pupil wavelets (cost model: >= {single:.0f} s on one thread; more where the window needs the "
        f"exact distance sum); Ctrl-C stops",
        err=True,
    )
    with tqdm(desc="huygens", unit="block", dynamic_ncols=True) as bar:

        def progress(done, total):
            if total and bar.total != total:
                bar.total = total
            bar.n = done
            bar.refresh()

        return compute(progress)
