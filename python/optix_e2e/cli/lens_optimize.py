"""``optix lens optimize``: classic least-squares optimization of a nominal design."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click

from ._common import AIMING, dumps, friendly_errors
from ..lens import BUNDLED_DIR, Lens, LensLoadError
from ..lens_optimizer import Constraints, Merit, optimize
from ..lens_optimizer import set_semi_diameters as _with_semi_diameters
from ..space import ParameterSpace, SpaceError


def _raw_lens(spec: str) -> tuple[dict, str]:
    """The prescription as written (catalog glass names kept), and its source."""
    path = Path(spec)
    if not path.is_file() and (BUNDLED_DIR / f"{spec}.json").is_file():
        path = BUNDLED_DIR / f"{spec}.json"
    if not path.is_file():
        Lens.load(spec)  # raises the usual "no such lens" error
        raise LensLoadError(f"{spec}: no such lens file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise LensLoadError(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON: {exc.msg}") from exc
    if isinstance(data, dict):
        data.setdefault("name", path.stem)
    Lens(data, source=str(path))  # validate with file-named errors
    return data, str(path)


def _floats(text: str | None, what: str) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise click.BadParameter(f"{what}: expected comma-separated numbers, got {text!r}") from None


@click.command("optimize")
@click.argument("lens_spec", metavar="LENS")
@click.option("--vars", "var_names", help="Comma-separated variables, e.g. s_1_radius,s_1_conic,s_2_thickness "
              "(default bounds around the current values; see optix_e2e.space).")
@click.option("--space", "space_file", type=click.Path(dir_okay=False),
              help="Parameter-space JSON (name, kind, surface, min, max, unit); its ranges are the bounds.")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Where to write the optimized lens JSON.")
@click.option("--summary", "summary_path", type=click.Path(dir_okay=False),
              help="Also write the JSON summary to this file.")
@click.option("--efl", type=float, help="Effective focal length target (mm).")
@click.option("--efl-tol", type=float, default=1e-3, show_default=True,
              help="Relative EFL tolerance for calling the target met.")
@click.option("--min-center", type=float, help="Minimum glass center thickness (mm).")
@click.option("--min-edge", type=float, help="Minimum glass edge thickness at the clear semi-diameter (mm).")
@click.option("--min-air-gap", type=float, help="Minimum air gap between optical surfaces, center and edge (mm).")
@click.option("--min-bfd", type=float, help="Minimum back focal distance, last vertex to image (mm).")
@click.option("--focus", type=click.Choice(["fixed", "paraxial"]), default="fixed", show_default=True,
              help="paraxial: solve the last thickness to the paraxial focus each evaluation (BFL solve).")
@click.option("--field-weights", help="Comma-separated weights, one per lens field (default equal).")
@click.option("--rings", type=click.IntRange(1, 32), default=6, show_default=True,
              help="Gaussian-quadrature pupil rings of the merit.")
@click.option("--arms", type=click.IntRange(2, 64), default=12, show_default=True,
              help="Pupil azimuths of the merit.")
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True)
@click.option("--max-iter", type=click.IntRange(1, 100000), default=200, show_default=True,
              help="Solver iterations (merit evaluations outside the Jacobian).")
@click.option("--set-semi-diameters", is_flag=True,
              help="Write each surface's clear semi-diameter from the optimized ray footprint.")
@click.option("--name", "new_name", help="Name to store in the output lens.")
@click.option("--description", help="Description to store in the output lens.")
@friendly_errors
def optimize_cmd(lens_spec, var_names, space_file, out_path, summary_path, efl, efl_tol, min_center,
                 min_edge, min_air_gap, min_bfd, focus, field_weights, rings, arms, aiming, max_iter,
                 set_semi_diameters, new_name, description):
    """Optimize LENS by trust-region damped least squares on the polychromatic RMS spot
    radius over its fields, under EFL / thickness / air-gap / BFD constraints."""
    from tqdm import tqdm

    raw, source = _raw_lens(lens_spec)
    lens = Lens(raw, source=source)
    if not var_names and not space_file:
        raise click.UsageError("give the variables: --vars NAMES and/or --space FILE")
    constraints = Constraints(efl=efl, efl_tol=efl_tol, min_center=min_center, min_edge=min_edge,
                              min_air_gap=min_air_gap, min_bfd=min_bfd)
    merit = Merit(lens, constraints, field_weights=_floats(field_weights, "--field-weights"),
                  rings=rings, arms=arms, aiming=aiming, focus=focus)
    params = []
    try:
        if space_file:
            params += ParameterSpace.load(space_file, lens.data).params
        if var_names:
            # default asphere bounds scale with the start's ray footprint
            footprint = merit.footprint(lens.data, lens.to_engine_json())
            params += ParameterSpace.from_names(var_names, lens.data, footprint).params
        space = ParameterSpace(params, source=space_file or "--vars")
    except SpaceError as exc:
        raise click.ClickException(str(exc)) from None

    bar = tqdm(total=None, unit="eval", desc="optimize", dynamic_ncols=True, file=sys.stderr)
    best = {"merit": math.inf}

    def progress(n, merit_um, worst, feasible):
        # the bar shows the best merit among designs meeting every constraint so far and
        # the worst violation of the latest evaluation
        bar.update(1)
        if feasible and merit_um < best["merit"]:
            best["merit"] = merit_um
        bar.set_postfix(best_feasible_um=f"{best['merit']:.4f}", violation=f"{worst:.1e}", refresh=False)

    try:
        res = optimize(raw, space, merit, max_nfev=max_iter, progress=progress)
    finally:
        bar.close()
    out = res.lens
    if set_semi_diameters:
        out = _with_semi_diameters(out, res.after["semi_diameters_mm"])
    else:
        small = [f"surface {i + 1}: {s['semi_diameter']} < {h:.4f} mm"
                 for i, (s, h) in enumerate(zip(out["surfaces"], res.after["semi_diameters_mm"]))
                 if s.get("semi_diameter") is not None and s["semi_diameter"] < h]
        if small:
            click.echo("warning: clear semi-diameters kept from the input now clip the beam ("
                       + "; ".join(small) + "); rerun with --set-semi-diameters", err=True)
    if new_name:
        out["name"] = new_name
    if description:
        out["description"] = description
    Lens(out, source=out_path)  # the result must be a valid prescription
    Path(out_path).write_text(json.dumps(out, indent=2) + "\n", encoding="utf-8")
    summary = {"lens": lens.name, "source": source, "out": out_path, "variables": space.to_json(),
               "constraints_requested": constraints.__dict__, "focus": focus, **res.summary()}
    text = dumps(summary, indent=2)
    if summary_path:
        Path(summary_path).write_text(text + "\n", encoding="utf-8")
    click.echo(text)
    after, before = res.after, res.before
    click.echo(f"merit (RMS spot) {before['merit_um']:.4f} um -> {after['merit_um']:.4f} um; "
               f"constraints {'met' if summary['constraints_satisfied'] else 'NOT met'}", err=True)

