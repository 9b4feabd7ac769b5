"""``optix lens optimize``: classic least-squares optimization of a nominal design."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click
import numpy as np

from ..io import write_text_atomic
from ..lens import BUNDLED_DIR, Lens, LensLoadError
from ..lens_design.optimizer import Constraints, LensProblem, Merit, optimize
from ..lens_design.optimizer import set_semi_diameters as _with_semi_diameters
from ..lens_design.space import ParameterSpace, SpaceError
from ._common import AIMING, FINITE, SEED, FiniteFloatRange, dumps, friendly_errors


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
    except RecursionError:
        raise LensLoadError(f"{path}: invalid JSON: nested too deeply to be a lens prescription") from None
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
@click.option(
    "--vars",
    "var_names",
    help="Comma-separated variables, e.g. s_1_radius,s_1_conic,s_2_thickness "
    "(default bounds around the current values; see optix_e2e.lens_design.space).",
)
@click.option(
    "--space",
    "space_file",
    type=click.Path(dir_okay=False),
    help="Parameter-space JSON (name, kind, surface, min, max, unit); its ranges are the bounds.",
)
@click.option(
    "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="Where to write the optimized lens JSON."
)
@click.option(
    "--summary", "summary_path", type=click.Path(dir_okay=False), help="Also write the JSON summary to this file."
)
@click.option("--efl", type=FINITE, help="Effective focal length target (mm).")
@click.option(
    "--efl-tol",
    type=FiniteFloatRange(min=0, min_open=True),
    default=1e-3,
    show_default=True,
    help="Relative EFL tolerance for calling the target met.",
)
@click.option("--min-center", type=FINITE, help="Minimum glass center thickness (mm).")
@click.option("--min-edge", type=FINITE, help="Minimum glass edge thickness at the clear semi-diameter (mm).")
@click.option("--min-air-gap", type=FINITE, help="Minimum air gap between optical surfaces, center and edge (mm).")
@click.option("--min-bfd", type=FINITE, help="Minimum back focal distance, last vertex to image (mm).")
@click.option(
    "--min-image-height",
    type=FINITE,
    help="Minimum image height (mm) of the chief ray (real trace, aimed per --aiming) at the largest field, "
    "e.g. the sensor's half-diagonal.",
)
@click.option(
    "--focus",
    type=click.Choice(["fixed", "paraxial"]),
    default="fixed",
    show_default=True,
    help="paraxial: solve the last thickness to the paraxial focus each evaluation (BFL solve).",
)
@click.option("--field-weights", help="Comma-separated weights, one per lens field (default equal).")
@click.option(
    "--rings",
    type=click.IntRange(1, 32),
    default=6,
    show_default=True,
    help="Gaussian-quadrature pupil rings of the merit.",
)
@click.option("--arms", type=click.IntRange(2, 64), default=12, show_default=True, help="Pupil azimuths of the merit.")
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True)
@click.option(
    "--merit",
    "merit_kind",
    type=click.Choice(["spot", "wavefront"]),
    default="spot",
    show_default=True,
    help="spot: polychromatic RMS spot radius (um); wavefront: RMS OPD (waves), piston and tilt removed.",
)
@click.option(
    "--tilt",
    type=click.Choice(["wavelength", "field"]),
    default=None,
    help="--merit wavefront: remove tilt per wavelength (Zemax's centroid reference; the default) or once "
    "per field (lateral colour counts).",
)
@click.option(
    "--max-iter",
    type=click.IntRange(1, 100000),
    default=200,
    show_default=True,
    help="Solver iterations (merit evaluations outside the Jacobian); with --global, per polish.",
)
@click.option(
    "--global",
    "global_",
    is_flag=True,
    help="Global search (Sobol' starts and Hammer jumps, each polished by damped least squares) "
    "instead of one local optimization from LENS.",
)
@click.option(
    "--minutes",
    type=FiniteFloatRange(min=0.01),
    default=None,
    help="--global: time budget (default 5 minutes when --rounds is not given).",
)
@click.option(
    "--rounds",
    type=click.IntRange(1, 100000),
    default=None,
    help="--global: number of rounds (repeatable for a seed; the time budget still applies if given).",
)
@click.option("--seed", type=SEED, default=None, help="--global: random seed (default 0).")
@click.option(
    "--workers",
    type=click.IntRange(1, 256),
    default=None,
    help="--global: worker processes (default: the CPU count, at most --batch).",
)
@click.option("--batch", type=click.IntRange(1, 1024), default=None, help="--global: polishes per round (default 4).")
@click.option(
    "--basins",
    "basins_path",
    type=click.Path(dir_okay=False),
    help="--global: also write every basin found (merit, constraint slack, values) as CSV here.",
)
@click.option(
    "--set-semi-diameters",
    is_flag=True,
    help="Write each surface's clear semi-diameter from the optimized ray footprint.",
)
@click.option("--name", "new_name", help="Name to store in the output lens.")
@click.option("--description", help="Description to store in the output lens.")
@friendly_errors
def optimize_cmd(
    lens_spec,
    var_names,
    space_file,
    out_path,
    summary_path,
    efl,
    efl_tol,
    min_center,
    min_edge,
    min_air_gap,
    min_bfd,
    min_image_height,
    focus,
    field_weights,
    rings,
    arms,
    aiming,
    merit_kind,
    tilt,
    max_iter,
    global_,
    minutes,
    rounds,
    seed,
    workers,
    batch,
    basins_path,
    set_semi_diameters,
    new_name,
    description,
):
    """Optimize LENS by trust-region damped least squares on the polychromatic RMS spot
    radius (or RMS wavefront error) over its fields, under EFL / thickness / air-gap / BFD
    constraints; --global searches many basins within the variables' ranges."""
    from tqdm import tqdm

    raw, source = _raw_lens(lens_spec)
    lens = Lens(raw, source=source)
    if not var_names and not space_file:
        raise click.UsageError("give the variables: --vars NAMES and/or --space FILE")
    given = [
        o
        for o, v in (
            ("--minutes", minutes),
            ("--rounds", rounds),
            ("--basins", basins_path),
            ("--seed", seed),
            ("--workers", workers),
            ("--batch", batch),
        )
        if v is not None
    ]
    if not global_ and given:
        raise click.UsageError(f"{', '.join(given)} go with --global")
    if tilt is not None and merit_kind != "wavefront":
        raise click.UsageError("--tilt goes with --merit wavefront")
    tilt = tilt or "wavelength"
    seed = 0 if seed is None else seed
    batch = batch or 4
    constraints = Constraints(
        efl=efl,
        efl_tol=efl_tol,
        min_center=min_center,
        min_edge=min_edge,
        min_air_gap=min_air_gap,
        min_bfd=min_bfd,
        min_image_height=min_image_height,
    )
    merit = Merit(
        lens,
        constraints,
        field_weights=_floats(field_weights, "--field-weights"),
        rings=rings,
        arms=arms,
        aiming=aiming,
        focus=focus,
        kind=merit_kind,
        tilt=tilt,
    )
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
    unit = merit.unit
    global_summary = None
    if global_:
        res, global_summary = _run_global(raw, space, merit, minutes, rounds, seed, workers, batch, max_iter)
    else:
        bar = tqdm(total=None, unit="eval", desc="optimize", dynamic_ncols=True, file=sys.stderr)
        best = {"merit": math.inf}

        def progress(n, value, worst, feasible):
            # the bar shows the best merit among designs meeting every constraint so far and
            # the worst violation of the latest evaluation
            bar.update(1)
            if feasible and value < best["merit"]:
                best["merit"] = value
            bar.set_postfix(
                {f"best_feasible_{unit}": f"{best['merit']:.4f}", "violation": f"{worst:.1e}"}, refresh=False
            )

        try:
            res = optimize(raw, space, merit, max_nfev=max_iter, progress=progress)
        finally:
            bar.close()
    out = res.lens
    if set_semi_diameters:
        out = _with_semi_diameters(out, res.after["semi_diameters_mm"])
    else:
        small = [
            f"surface {i + 1}: {s['semi_diameter']} < {h:.4f} mm"
            for i, (s, h) in enumerate(zip(out["surfaces"], res.after["semi_diameters_mm"]))
            if s.get("semi_diameter") is not None and s["semi_diameter"] < h
        ]
        if small:
            click.echo(
                "warning: clear semi-diameters kept from the input now clip the beam ("
                + "; ".join(small)
                + "); rerun with --set-semi-diameters",
                err=True,
            )
    if new_name:
        out["name"] = new_name
    if description:
        out["description"] = description
    Lens(out, source=out_path)  # the result must be a valid prescription
    write_text_atomic(out_path, json.dumps(out, indent=2) + "\n")
    summary = {
        "lens": lens.name,
        "source": source,
        "out": out_path,
        "variables": space.to_json(),
        "constraints_requested": constraints.__dict__,
        "focus": focus,
        "merit": merit_kind,
        "tilt": tilt if merit_kind == "wavefront" else None,
        **res.summary(),
    }
    if global_summary is not None:
        summary["global"] = global_summary
        if basins_path:
            from ..lens_design.global_search import basins_csv

            write_text_atomic(basins_path, basins_csv(global_summary))
    text = dumps(summary, indent=2)
    if summary_path:
        write_text_atomic(summary_path, text + "\n")
    click.echo(text)
    after, before = res.after, res.before
    what = "RMS spot" if merit_kind == "spot" else "RMS wavefront"
    click.echo(
        f"merit ({what}) {before['merit']:.4f} {unit} -> {after['merit']:.4f} {unit}; "
        f"constraints {'met' if summary['constraints_satisfied'] else 'NOT met'}",
        err=True,
    )
    if global_summary is not None:
        g = global_summary
        click.echo(
            f"global search: {g['rounds']} rounds, {g['polishes']} polishes, {g['basins_found']} basins, "
            f"{g['nfev']} evaluations, {g['wall_s']:.1f} s (stopped by {g['stopped_by']})",
            err=True,
        )
        for k, b in enumerate(g["basins"][:10]):
            slack = "-" if b["min_slack"] is None else f"{b['min_slack']:+.3f} mm ({b['tightest']})"
            click.echo(
                f"  basin {k + 1}: merit {b['merit']:.4f} {unit}  "
                f"{'feasible' if b['feasible'] else 'infeasible'}  min slack {slack}  "
                f"{len(b['active'])} active  visits {b['visits']}  found by {b['found_by']}",
                err=True,
            )


def _run_global(raw, space, merit, minutes, rounds, seed, workers, batch, max_iter):
    """The global search with a progress bar; returns (OptimizeResult, its JSON summary)."""
    import os

    from tqdm import tqdm

    from ..lens_design.global_search import global_search

    if minutes is None and rounds is None:
        minutes = 5.0
    workers = workers or min(os.cpu_count() or 1, batch)
    problem = LensProblem(raw, space, merit)
    before = problem.report(problem.u0)
    bar = tqdm(total=None, unit="polish", desc="global search", dynamic_ncols=True, file=sys.stderr)

    def progress(basin, state):
        bar.update(1)
        bar.set_postfix(
            {f"best_{merit.unit}": f"{state.best.merit:.4f}", "basins": len(state.basins), "round": state.rounds},
            refresh=False,
        )

    try:
        g = global_search(
            problem,
            minutes=minutes,
            rounds=rounds,
            seed=seed,
            workers=workers,
            batch=batch,
            polish_nfev=max_iter,
            progress=progress,
        )
    finally:
        bar.close()
    res = problem.result(np.asarray(g.best.u), before, g.nfev, f"global search, {g.stopped}", [m for _, m in g.history])
    summary = g.summary()
    for b in summary["basins"] + [summary["best"]]:
        b["values"] = dict(zip(space.names, map(float, problem.x(b.pop("u")))))
    summary.update(
        {
            "seed": seed,
            "minutes": minutes,
            "rounds_requested": rounds,
            "batch": batch,
            "workers": workers,
            "polish_max_iter": max_iter,
        }
    )
    return res, summary
