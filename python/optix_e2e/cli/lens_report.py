"""``optix lens plot`` (layout figure) and ``optix lens report`` (layout, spot diagrams,
MTF and a JSON summary).  Register with ``lens.add_command(plot)`` and
``lens.add_command(report)``."""

from __future__ import annotations

import time
from pathlib import Path

import click

from ._common import AIMING, FiniteFloatRange, dumps, friendly_errors, load_lens

FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def _floats(text: str | None, what: str) -> list[float] | None:
    """'0,14,20' -> [0.0, 14.0, 20.0]; None stays None."""
    if text is None:
        return None
    try:
        vals = [float(t) for t in text.replace(" ", "").split(",") if t]
    except ValueError:
        raise click.BadParameter(f"{text!r} is not a comma-separated list of numbers", param_hint=what) from None
    if not vals:
        raise click.BadParameter("empty list", param_hint=what)
    return vals


def _fields(text: str | None) -> list[float] | None:
    vals = _floats(text, "--fields")
    if vals is not None and any(not (0.0 <= f < 90.0) for f in vals):
        raise click.BadParameter(f"field angles must lie in [0, 90) degrees, got {text}", param_hint="--fields")
    return vals


FIELDS = click.option(
    "--fields", default=None, metavar="F1,F2,...", help="Field angles in degrees (default: the lens's fields)."
)


@click.command("plot")
@click.argument("lens_spec", metavar="LENS")
@click.option(
    "--out",
    "out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Output figure (.png, .pdf or .svg).",
)
@FIELDS
@click.option(
    "--rays",
    type=click.IntRange(1, 101),
    default=9,
    show_default=True,
    help="Rays per field across the pupil (meridional fan).",
)
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True)
@click.option(
    "--wavelength-nm",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Default: the lens's primary wavelength.",
)
@friendly_errors
def plot(lens_spec, out, fields, rays, aiming, wavelength_nm):
    """Draw the y-z cross-section of LENS with ray fans for several fields."""
    if out.suffix.lower() not in FIGURE_SUFFIXES:
        raise click.BadParameter(f"{out.name}: use one of {', '.join(FIGURE_SUFFIXES)}", param_hint="--out")
    lens_ = load_lens(lens_spec)
    from ..lens_design.plots import save_layout_png

    out.parent.mkdir(parents=True, exist_ok=True)
    res = save_layout_png(out, lens_, fields=_fields(fields), rays=rays, aiming=aiming, wavelength_nm=wavelength_nm)
    fans = [{"field_deg": f["field_deg"], "rays": len(f["status"]), "reached_image": f["n_image"]} for f in res["fans"]]
    click.echo(dumps({"lens": lens_.name, "out": str(out), "aiming": aiming, "fields": fans}))


@click.command("report")
@click.argument("lens_spec", metavar="LENS")
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Output directory (created if needed).",
)
@FIELDS
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True)
@click.option("--rays", type=click.IntRange(1, 101), default=9, show_default=True, help="Rays per field in the layout.")
@click.option(
    "--freqs",
    default=None,
    metavar="F1,F2,...",
    help="Frequencies (cycles/mm) whose MTF goes into report.json "
    "[default: 10,20,40,85.32 (5.86 um pixel Nyquist),100].",
)
@click.option(
    "--max-freq",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Highest MTF frequency (cycles/mm) [default: the diffraction cutoff].",
)
@click.option("--per-wavelength", is_flag=True, help="Also draw each wavelength's MTF.")
@click.option(
    "--psf-method",
    type=click.Choice(["fft", "huygens"]),
    default="fft",
    show_default=True,
    help="PSFs the MTF is computed from (huygens: slower, the reference at large fields).",
)
@friendly_errors
def report(lens_spec, out, fields, aiming, rays, freqs, max_freq, per_wavelength, psf_method):
    """Write OUT/layout.png, spots.png, mtf.png and report.json for LENS.

    report.json holds the first-order data and, per field, the polychromatic RMS spot,
    relative illumination, MTF (tangential, sagittal, diffraction limit) at the chosen
    frequencies and the MTF curves.
    """
    from ..io import claim_out_dir
    from ..lens_design.report import DEFAULT_MTF_FREQS, write_report

    claim_out_dir(out, "lens report", {"layout.png", "spots.png", "mtf.png", "report.json"})
    lens_ = load_lens(lens_spec)
    freq_list = _floats(freqs, "--freqs") or list(DEFAULT_MTF_FREQS)
    if any(f < 0 for f in freq_list):
        raise click.BadParameter("frequencies must be >= 0", param_hint="--freqs")
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        click.echo(f"[{time.perf_counter() - t0:6.2f} s] {msg}", err=True)

    rep = write_report(
        lens_,
        out,
        fields=_fields(fields),
        aiming=aiming,
        rays=rays,
        freqs=freq_list,
        max_freq=max_freq,
        per_wavelength=per_wavelength,
        psf_method=psf_method,
        progress=progress,
    )
    progress(f"wrote {', '.join(str(out / f) for f in rep['files'])}")
    par = rep["paraxial"]
    click.echo(f"{lens_.name}: EFL {par['efl_mm']:.4f} mm, f/{par['f_number']:.3f}, aiming {aiming}")
    click.echo(
        f"  {'field':>7}  {'RMS spot':>9}  {'rel.ill.':>8}  MTF T/S at "
        + ", ".join(f"{q:g}" for q in freq_list)
        + " c/mm"
    )
    for row in rep["fields"]:
        mtf = "  ".join(f"{v['tangential']:.3f}/{v['sagittal']:.3f}" for v in row["mtf"].values())
        click.echo(
            f"  {row['field_deg']:>5g} d  {row['rms_spot_um']:>6.2f} um  {_ri(row['relative_illumination'])}  {mtf}"
        )
        for w in row["warnings"]:
            click.echo(f"  warning: {w}", err=True)


def _ri(v) -> str:
    """Relative illumination for the table; an afocal system has none."""
    return f"{v:>8.3f}" if v is not None else f"{'-':>8}"
