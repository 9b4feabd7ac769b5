"""``optix lens ...``: prescription summaries."""

from __future__ import annotations

import click

from ._common import AIMING, dumps, friendly_errors, load_lens

PARAXIAL_KEYS = ("efl_mm", "bfl_mm", "f_number", "epd_mm", "total_track_mm")


@click.group()
def lens():
    """Inspect lens prescriptions."""


@lens.command("info")
@click.argument("lens_spec", metavar="LENS")
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True,
              help="Ray aiming for the spot figures.")
@click.option("--rings", type=click.IntRange(1, 2048), default=128, show_default=True,
              help="Hexapolar rings per wavelength for the RMS spot.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
@friendly_errors
def info(lens_spec, aiming, rings, as_json):
    """First-order data and per-field polychromatic RMS spot of LENS."""
    lens_ = load_lens(lens_spec)
    par = lens_.paraxial()
    fields = []
    for f in lens_.fields_deg:
        s = lens_.spot(f, rings=rings, aiming=aiming)
        fields.append({
            "field_deg": f,
            "rms_spot_um": s["rms_um"],
            "relative_illumination": s["relative_illumination"],
            "vignetting": s.get("vignetting"),
            "chief_y_mm": s.get("chief_y_mm"),
            "n_rays": s.get("n_rays"),
        })
    out = {"lens": lens_.name, "source": lens_.source, "aiming": aiming,
           "wavelengths_nm": lens_.wavelengths_nm,
           "wavelength_weights": lens_.wavelength_weights,
           "primary_wavelength_nm": lens_.primary_wavelength_nm,
           **{k: par[k] for k in PARAXIAL_KEYS}, "paraxial": par, "fields": fields}
    if as_json:
        click.echo(dumps(out))
        return
    click.echo(f"{lens_.name}  ({lens_.source})")
    click.echo(f"  EFL {par['efl_mm']:.4f} mm   BFL {par['bfl_mm']:.4f} mm   f/{par['f_number']:.3f}"
               f"   EPD {par['epd_mm']:.4f} mm   total track {par['total_track_mm']:.4f} mm")
    wl = ", ".join(f"{w:g}" for w in lens_.wavelengths_nm)
    click.echo(f"  wavelengths {wl} nm (primary {lens_.primary_wavelength_nm:g}), aiming {aiming}")
    click.echo(f"  {'field (deg)':>11}  {'RMS spot (um)':>13}  {'rel. illum.':>11}")
    for row in fields:
        click.echo(f"  {row['field_deg']:>11.3f}  {row['rms_spot_um']:>13.4f}  {row['relative_illumination']:>11.4f}")
