"""``optix lens ...``: prescription summaries and format conversion (JSON <-> Zemax .zmx)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ..lens import Lens
from ..lens.text import printable
from ._common import AIMING, dumps, friendly_errors, load_lens

PARAXIAL_KEYS = ("efl_mm", "bfl_mm", "f_number", "epd_mm", "total_track_mm")


@click.group()
def lens():
    """Inspect and convert lens prescriptions (LENS: .json, .zmx or a bundled name)."""


@lens.command("info")
@click.argument("lens_spec", metavar="LENS")
@click.option(
    "--aiming",
    type=AIMING,
    default="paraxial",
    show_default=True,
    help="Ray aiming for the spot and wavefront figures.",
)
@click.option(
    "--rings",
    type=click.IntRange(1, 2048),
    default=128,
    show_default=True,
    help="Hexapolar rings per wavelength for the RMS spot.",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
@click.option(
    "--lenient",
    is_flag=True,
    help="Reading .zmx: list unknown keywords as ignored instead of failing (known-unsupported features still fail).",
)
@friendly_errors
def info(lens_spec, aiming, rings, as_json, lenient):
    """First-order data, Petzval sum, and per-field polychromatic RMS spot, RMS wavefront
    error (piston and tilt removed per wavelength) and relative illumination of LENS."""
    if Path(lens_spec).suffix.lower() == ".zmx" and Path(lens_spec).is_file():
        lens_ = Lens.from_file(lens_spec, strict=not lenient)
    else:
        lens_ = load_lens(lens_spec)
    par = lens_.paraxial()
    fields = []
    for f in lens_.fields_deg:
        s = lens_.spot(f, rings=rings, aiming=aiming)
        fields.append(
            {
                "field_deg": f,
                "rms_spot_um": s["rms_um"],
                "relative_illumination": s["relative_illumination"],
                "vignetting": s.get("vignetting"),
                "chief_y_mm": s.get("chief_y_mm"),
                "n_rays": s.get("n_rays"),
                # polychromatic RMS wavefront error, piston and tilt removed per wavelength
                "rms_wavefront_waves": (
                    _rms_wavefront(lens_, f, aiming) if s["relative_illumination"] is not None else None
                ),  # None: afocal
            }
        )
    # a lens whose image of the field folds: the engine refuses its relative illumination in RGB
    # PSFs and datasets (spot::field_fold), and the per-field value above misses light
    fold = lens_.field_fold(aiming=aiming) if lens_.max_field_deg > 0 else None
    warnings = (
        [
            f"the image of the field folds: at pupil point ({fold['px']:.2f}, {fold['py']:.2f}) the image "
            f"height falls by {-fold['step_mm']:.4g} mm near {fold['field_deg']:.3g} deg; rays of different "
            f"fields cross, the relative illumination above is not the image's (a dataset would record the "
            f"design as failed)"
        ]
        if fold
        else []
    )
    out = {
        "lens": lens_.name,
        "source": lens_.source,
        "aiming": aiming,
        "warnings": warnings,
        "wavelengths_nm": lens_.wavelengths_nm,
        "wavelength_weights": lens_.wavelength_weights,
        "primary_wavelength_nm": lens_.primary_wavelength_nm,
        # null: the object at infinity
        "object_distance_mm": lens_.object_distance if math.isfinite(lens_.object_distance) else None,
        **{k: par[k] for k in PARAXIAL_KEYS},
        "paraxial": par,
        **lens_.petzval(),
        "fields": fields,
    }
    if as_json:
        click.echo(dumps(out))
        return
    click.echo(printable(f"{lens_.name}  ({lens_.source})"))  # a .zmx NAME may hold escape bytes
    click.echo(
        f"  EFL {par['efl_mm']:.4f} mm   BFL {par['bfl_mm']:.4f} mm   f/{par['f_number']:.3f}"
        f"   EPD {par['epd_mm']:.4f} mm   total track {par['total_track_mm']:.4f} mm"
    )
    if math.isfinite(lens_.object_distance):
        click.echo(
            f"  object {lens_.object_distance:.4f} mm before surface 1; image plane "
            f"{-par['back_focus_shift_mm']:+.4f} mm from the object's paraxial image"
        )
    wl = ", ".join(f"{w:g}" for w in lens_.wavelengths_nm)
    click.echo(f"  wavelengths {wl} nm (primary {lens_.primary_wavelength_nm:g}), aiming {aiming}")
    click.echo(f"  Petzval sum {out['petzval_sum_per_mm']:.5f} 1/mm (Petzval radius {out['petzval_radius_mm']:.2f} mm)")
    click.echo(f"  {'field (deg)':>11}  {'RMS spot (um)':>13}  {'RMS WFE (waves)':>15}  {'rel. illum.':>11}")
    for row in fields:
        ri = row["relative_illumination"]
        ri_text = f"{ri:>11.4f}" if ri is not None else f"{'- (afocal)':>11}"
        wfe = row["rms_wavefront_waves"]
        wfe_text = f"{wfe:>15.4f}" if wfe is not None else f"{'-':>15}"
        click.echo(f"  {row['field_deg']:>11.3f}  {row['rms_spot_um']:>13.4f}  {wfe_text}  {ri_text}")
    for w in warnings:
        click.echo(printable(f"  warning: {w}"))


def bundled_summary(name: str) -> dict:
    """One bundled lens at a glance: what ``optix lens list`` prints."""
    from ..lens import BUNDLED_DIR, BUNDLED_SURROGATES

    lens_ = Lens.load(name)
    par = lens_.paraxial()
    # an element is a slab of one glass: each surface followed by a non-air medium starts one
    n_elements = sum(
        1 for s in lens_.data["surfaces"] if not (isinstance(s["material"], str) and s["material"].lower() == "air")
    )
    space = BUNDLED_DIR / "spaces" / f"{name}.toml"
    sur = BUNDLED_SURROGATES.get(name)
    e2e = BUNDLED_SURROGATES.get(f"{name}-e2e")  # the end-to-end design space around this lens
    det = BUNDLED_SURROGATES.get(f"{name}-detect")  # ... and with the f-number, for detection
    return {
        "name": name,
        "elements": n_elements,
        "efl_mm": par["efl_mm"],
        "f_number": par["f_number"],
        "full_field_deg": 2.0 * max(abs(f) for f in lens_.fields_deg),
        "wavelengths_nm": lens_.wavelengths_nm,
        "source": lens_.data.get("source"),
        "description": lens_.data.get("description"),
        "parameter_space": f"spaces/{space.name}" if space.is_file() else None,
        "surrogate": sur if sur and (BUNDLED_DIR / sur).is_file() else None,
        "e2e_space": f"spaces/{name}-e2e.toml" if (BUNDLED_DIR / "spaces" / f"{name}-e2e.toml").is_file() else None,
        "e2e_surrogate": e2e if e2e and (BUNDLED_DIR / e2e).is_file() else None,
        "detect_space": f"spaces/{name}-detect.toml"
        if (BUNDLED_DIR / "spaces" / f"{name}-detect.toml").is_file()
        else None,
        "detect_surrogate": det if det and (BUNDLED_DIR / det).is_file() else None,
    }


@lens.command("list")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list instead of a table.")
@friendly_errors
def list_cmd(as_json):
    """The bundled lenses: elements, EFL, f-number, full field, source, and whether a
    parameter space and a trained surrogate ship for each."""
    from ..lens import bundled_lenses

    rows = [bundled_summary(n) for n in bundled_lenses()]
    if as_json:
        click.echo(dumps(rows, indent=2))
        return
    click.echo(f"{'name':<18} {'elements':>8} {'EFL (mm)':>9} {'f/#':>6} {'field':>7}  space  surrogate  source")
    for r in rows:
        click.echo(
            f"{r['name']:<18} {r['elements']:>8} {r['efl_mm']:>9.3f} {r['f_number']:>6.2f} "
            f"{r['full_field_deg']:>6.2f}d  {'yes' if r['parameter_space'] else 'no':<5}  "
            f"{'yes' if r['surrogate'] else ('e2e' if r['e2e_surrogate'] else 'no'):<9}  {r['source'] or '-'}"
        )


def _rms_wavefront(lens_, field_deg, aiming):
    """Polychromatic RMS wavefront error of a field (waves), or None where the reference
    sphere is undefined (image-space telecentric), the chief ray fails or no ray of a
    wavelength arrives."""
    from ..engine import EngineError

    try:
        wf = lens_.wavefront(field_deg, aiming=aiming)
        return None if (wf["status"] != 0).all(axis=1).any() else wf["rms_waves_poly"]
    except EngineError:
        return None


FORMATS = (".json", ".zmx")


@lens.command("convert")
@click.argument("src", metavar="IN")
@click.argument("dst", metavar="OUT", type=click.Path(dir_okay=False))
@click.option("--utf16", is_flag=True, help="Write .zmx as UTF-16 (OpticStudio's own encoding) instead of UTF-8.")
@click.option(
    "--lenient",
    is_flag=True,
    help="Reading .zmx: list unknown keywords as ignored instead of failing (known-unsupported features still fail).",
)
@friendly_errors
def convert(src, dst, utf16, lenient):
    """Convert IN to OUT; formats by extension (.json, .zmx). IN may be a bundled name.

    Prints what a .zmx import ignored, and the paraxial EFL/BFL of both sides.
    """
    out = Path(dst)
    if out.suffix.lower() not in FORMATS:
        raise click.UsageError(f"OUT {dst}: unknown extension {out.suffix!r} (use .json or .zmx)")
    if Path(src).suffix.lower() not in FORMATS + ("",):
        raise click.UsageError(f"IN {src}: unknown extension {Path(src).suffix!r} (use .json or .zmx)")
    if Path(src).suffix.lower() == ".zmx" and Path(src).is_file():
        lens_ = Lens.from_file(src, strict=not lenient)
    else:
        lens_ = load_lens(src)
    imp = lens_.zemax_import
    if imp is not None:
        for note in imp.notes:  # names and glass names from the file: their escape bytes shown, not sent
            click.echo(printable(f"note: {note}"), err=True)
        if imp.ignored:
            click.echo("ignored (no effect on the nominal optics, see docs/zemax.md):", err=True)
            click.echo("\n".join("  " + printable(line) for line in imp.ignored_summary().split("\n")), err=True)
    lens_.save(out, encoding="utf-16" if utf16 else "utf-8")
    back = Lens.from_file(out, strict=True)
    a, b = lens_.paraxial(), back.paraxial()
    click.echo(
        f"wrote {out} ({len(back.surfaces)} surfaces)   EFL {a['efl_mm']:.9g} -> {b['efl_mm']:.9g} mm"
        f"   BFL {a['bfl_mm']:.9g} -> {b['bfl_mm']:.9g} mm"
    )


@lens.command("survey")
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    default=None,
    help="Also write survey.json (summary) and survey.csv (one row per file) here.",
)
@friendly_errors
def survey_cmd(folder, out):
    """Import rate of every .zmx under FOLDER (read leniently): how many import, trace
    (paraxial EFL, a real chief and marginal ray) and match the nominal focal length of
    their NAME/NOTE line within 1 %, and the top reasons for what is refused."""
    from ..io import claim_out_dir
    from ..lens.zemax.survey import results_csv, survey

    if out:
        claim_out_dir(out, "lens survey", {"survey.json", "survey.csv"})
    summary, results = survey(Path(folder))
    text = dumps(summary, indent=1, ensure_ascii=False)
    if out:  # both texts made before either file is touched, each written whole or not at all
        from ..io import write_text_atomic

        table = results_csv(results)
        Path(out).mkdir(parents=True, exist_ok=True)
        write_text_atomic(Path(out) / "survey.json", text + "\n")
        write_text_atomic(Path(out) / "survey.csv", table)
    click.echo(text)


# Subcommands that live in their own modules (one module per subcommand).
from .lens_optimize import optimize_cmd  # noqa: E402
from .lens_report import plot, report  # noqa: E402

lens.add_command(optimize_cmd)
lens.add_command(plot)
lens.add_command(report)
