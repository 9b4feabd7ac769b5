"""``optix tolerance LENS --space SPACE --out DIR``: sensitivities, ranges from a budget, MC yield."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import click

from ..io import save_figure, write_csv_atomic, write_record_atomic
from ..lens import Lens
from ..lens_design.optimizer import Merit
from ..lens_design.space import SPACES_DIR, ParameterSpace, SpaceError, bundled_spaces
from ..lens_design.tolerance import DEFAULT_PUPIL
from ._common import FINITE, SEED, FiniteFloatRange, dumps, friendly_errors

MC_SPACES = ("proposed", "given")


def resolve_space(spec: str) -> Path:
    """A space file path from a path or a bundled lens's name."""
    path = Path(spec)
    if path.is_file():
        return path
    bundled = SPACES_DIR / f"{spec}.toml"
    if bundled.is_file():
        return bundled
    raise SpaceError(
        f"{spec!r} is neither a space file nor a bundled lens with a space (bundled: {', '.join(bundled_spaces())})"
    )


def _lens_ref(lens_spec: str, out_dir: Path) -> str:
    """How proposed.toml names the lens: a bundled name as is, a file relative to DIR."""
    path = Path(lens_spec)
    if path.is_file():
        return os.path.relpath(path.resolve(), out_dir.resolve())
    return lens_spec


def _num(v: float) -> str:
    return repr(float(v)) if math.isfinite(v) else ""


def write_csv(path: Path, sens, alloc, given: ParameterSpace) -> None:
    by = {a.name: a for a in alloc}
    g = {p.name: p for p in given.params}
    rank = {r.param.name: i + 1 for i, r in enumerate(sens.ranking())}
    rows = [  # the header, then one row per parameter
        [
            "rank",
            "name",
            "kind",
            "surface",
            "unit",
            "nominal",
            "step",
            "worst_m2_um",
            "worst_m1_um",
            "worst_p1_um",
            "worst_p2_um",
            "d_worst_step_um",
            "d_mean_step_um",
            "lin_worst_um_per_unit",
            "quad_worst_um_per_unit2",
            "lin_mean_um_per_unit",
            "quad_mean_um_per_unit2",
            "fit_rms_um",
            "share_um",
            "tolerance",
            "capped",
            "proposed_min",
            "proposed_max",
            "given_min",
            "given_max",
            "growth_model_um",
            "growth_traced_um",
            "failed",
        ]
    ]
    for r in sens.rows:
        a = by[r.param.name]
        lw, qw = r.worst_fit()
        lm, qm = r.mean_fit()
        gp = g.get(r.param.name)
        rows.append(
            [
                rank[r.param.name],
                r.param.name,
                r.param.kind,
                r.param.surface,
                r.param.unit,
                _num(r.nominal),
                _num(r.step),
                *(_num(v) for v in r.worst),
                _num(r.d_worst_step),
                _num(r.d_mean_step),
                _num(lw),
                _num(qw),
                _num(lm),
                _num(qm),
                _num(r.fit_rms_um),
                _num(a.share_um),
                _num(a.tolerance),
                int(a.capped),
                _num(a.lo),
                _num(a.hi),
                _num(gp.min) if gp else "",
                _num(gp.max) if gp else "",
                _num(a.growth_model_um),
                _num(a.growth_traced_um),
                "; ".join(r.failed + a.traced_failed),
            ]
        )
    write_csv_atomic(path, rows)


def plot_sensitivity(path: Path, sens, alloc, budget_um: float) -> None:
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    order = sens.ranking()
    by = {a.name: a for a in alloc}
    names = [r.param.name + (" (cap)" if by[r.param.name].capped else "") for r in order]
    traced = np.array([by[r.param.name].growth_traced_um for r in order], float)
    model = np.array([by[r.param.name].growth_model_um for r in order], float)
    step = np.array([r.d_worst_step for r in order], float)
    n = len(order)
    fig = Figure(figsize=(10, 0.32 * n + 1.8), layout="constrained")
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(1, 2, sharey=True)
    y = np.arange(n)
    ax1.barh(y, np.nan_to_num(step, nan=0.0), color="tab:gray")
    ax1.set_xlabel("|change| of worst-field RMS at +-1 step (um)")
    ax1.set_title("sensitivity (default steps)")
    finite = np.isfinite(traced)
    ax2.barh(y[finite], traced[finite], color="tab:blue", label="traced at the range ends")
    ax2.plot(model, y, "k|", ms=12, label="quadratic model")
    for yi in y[~finite]:
        ax2.text(0, yi, " design fails at an end", va="center", fontsize=7, color="tab:red")
    share = alloc[0].share_um if alloc else math.nan
    ax2.axvline(share, color="tab:red", ls="--", lw=1, label=f"RSS share {share:.3g} um")
    ax2.set_xlabel("growth of worst-field RMS over the proposed range (um)")
    ax2.set_title(f"at the proposed tolerances (budget {budget_um:.3g} um)")
    ax2.legend(fontsize=7, loc="lower right")
    ax1.set_yticks(y, names, fontsize=8)
    ax1.invert_yaxis()
    save_figure(fig, path, dpi=110)


def plot_yield(path: Path, mc, nominal_um: float, label: str) -> None:
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    w = mc.worst[np.isfinite(mc.worst)]
    if len(w):
        ax.hist(w, bins=max(10, min(60, len(w) // 5)), color="tab:blue", alpha=0.8)
    ax.axvline(mc.spec_um, color="tab:red", ls="--", label=f"spec {mc.spec_um:.3g} um")
    ax.axvline(nominal_um, color="k", ls=":", label=f"nominal {nominal_um:.3g} um")
    ax.set_xlabel("worst-field RMS spot (um)")
    ax.set_ylabel("designs")
    ax.set_title(
        f"Monte Carlo, {label} ranges: yield {mc.yield_:.3f} +- {mc.yield_stderr:.3f} "
        f"(n = {mc.n}, failed {mc.n_failed})",
        fontsize=10,
    )
    ax.legend(fontsize=8)
    save_figure(fig, path, dpi=110)


@click.command("tolerance")
@click.argument("lens_spec", metavar="LENS")
@click.option(
    "--space",
    "space_spec",
    required=True,
    metavar="SPACE",
    help="Space TOML file, or a bundled lens's name (its bundled space).",
)
@click.option(
    "--budget-um",
    type=FINITE,
    default=None,
    help="Allowed growth of the worst-field RMS spot (um); default 20 % of the nominal's "
    "(or spec - nominal with --spec-um).",
)
@click.option(
    "--spec-um",
    type=FINITE,
    default=None,
    help="Worst-field RMS spot a design must meet for the yield (um); default nominal + budget.",
)
@click.option(
    "--mc",
    "n_mc",
    type=click.IntRange(0, 1_000_000),
    default=200,
    show_default=True,
    help="Monte Carlo designs (0: no Monte Carlo).",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--mc-space",
    type=click.Choice(MC_SPACES),
    default="proposed",
    show_default=True,
    help="Draw the Monte Carlo designs from the proposed ranges or the given space's.",
)
@click.option(
    "--step-scale",
    type=FiniteFloatRange(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="Scale every default sensitivity step (docs/tolerance.md).",
)
@click.option(
    "--rings",
    type=click.IntRange(1, 32),
    default=None,
    help="Gaussian-quadrature pupil rings of the RMS spot [default: 6; 32 with --apertures fixed].",
)
@click.option(
    "--arms",
    type=click.IntRange(2, 64),
    default=None,
    help="Pupil azimuths of the RMS spot [default: 12; 64 with --apertures fixed].",
)
@click.option(
    "--apertures",
    type=click.Choice(list(DEFAULT_PUPIL)),
    default="free",
    show_default=True,
    help="Trace with free apertures (no clipping) or the lens's clear semi-diameters (the stop's dropped: "
    "the iris follows the f-number), as optix dataset --apertures fixed; clipped rays are vignetting.",
)
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False),
    help="Output folder (sensitivity.csv, tolerance.json, proposed.toml, *.png).",
)
@friendly_errors
def tolerance(
    lens_spec, space_spec, budget_um, spec_um, n_mc, seed, mc_space, step_scale, rings, arms, apertures, out_dir
):
    """Tolerance analysis of LENS over the parameters of SPACE.

    Traces each parameter at +-1 and +-2 steps, fits per-field quadratic models of the RMS
    spot, shares the budget by root-sum-square into a +- tolerance per parameter
    (proposed.toml), and estimates the yield by Monte Carlo.  Prints one JSON line.
    """
    from tqdm import tqdm

    from ..io import claim_out_dir
    from ..lens_design import tolerance as tol

    claim_out_dir(
        out_dir,
        "tolerance analysis",
        {"proposed.toml", "sensitivity.csv", "sensitivity.png", "yield.png", "tolerance.json"},
    )
    from ..lens_design.constraints import Limits

    for opt, v in (("--budget-um", budget_um), ("--spec-um", spec_um)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise click.ClickException(f"{opt} must be a positive number of um, got {v}")
    if not (math.isfinite(step_scale) and step_scale > 0):
        raise click.ClickException(f"--step-scale must be > 0, got {step_scale}")
    lens = Lens.load(lens_spec)
    space_path = resolve_space(space_spec)
    given = ParameterSpace.load(space_path, lens.data)
    warnings = [f"nominal outside the space: {m}" for m in tol.check_space_fits(given, lens.data)]
    for w in warnings:
        click.echo(f"warning: {w}", err=True)
    limits = Limits.from_dict(given.constraints, f"{given.source}: [constraints]")
    # a clipped pupil is not the smooth integrand Gaussian quadrature is exact for: its edge
    # field converges slowly (docs/tolerance.md), so fixed apertures get the finest grid
    default_rings, default_arms = DEFAULT_PUPIL[apertures]
    rings, arms = rings or default_rings, arms or default_arms
    merit = Merit(lens, rings=rings, arms=arms)

    bar = tqdm(
        total=len(given) * len(tol.OFFSETS), unit="trace", desc="sensitivity", file=sys.stderr, dynamic_ncols=True
    )
    try:
        sens = tol.sensitivity(
            given,
            lens,
            merit,
            step_scale=step_scale,
            progress=lambda done, total: bar.update(done - bar.n),
            apertures=apertures,
        )
    finally:
        bar.close()
    w0 = sens.nominal_worst
    if budget_um is None:
        if spec_um is not None:
            if spec_um <= w0:
                raise click.ClickException(
                    f"--spec-um {spec_um} is not above the nominal worst-field RMS "
                    f"{w0:.4g} um; give --budget-um as well"
                )
            budget_um = spec_um - w0
        else:
            budget_um = 0.2 * w0
    if spec_um is None:
        spec_um = w0 + budget_um
    alloc = tol.allocate(sens, budget_um, given, merit=merit, lens=lens, apertures=apertures)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    desc = (
        f"proposed by optix tolerance: worst-field RMS budget {budget_um:.4g} um over the nominal "
        f"{w0:.4g} um, RSS shares {alloc[0].share_um:.4g} um (cut to the ranges of {space_spec})"
    )
    proposed = tol.proposed_space(sens, alloc, given, source=str(out / "proposed.toml"), description=desc)
    proposed.save_toml(out / "proposed.toml", lens_ref=_lens_ref(lens_spec, out))
    ParameterSpace.load(out / "proposed.toml", lens.data)  # must read back

    mc = None
    if n_mc:
        space_mc = proposed if mc_space == "proposed" else given
        bar = tqdm(total=n_mc, unit="design", desc="monte carlo", file=sys.stderr, dynamic_ncols=True)
        try:
            mc = tol.monte_carlo(
                space_mc,
                lens,
                merit,
                n_mc,
                spec_um,
                seed=seed,
                limits=limits,
                progress=lambda done, total: bar.update(done - bar.n),
                apertures=apertures,
            )
        finally:
            bar.close()

    write_csv(out / "sensitivity.csv", sens, alloc, given)
    plot_sensitivity(out / "sensitivity.png", sens, alloc, budget_um)
    if mc is not None:
        plot_yield(out / "yield.png", mc, w0, mc_space)
    ranking = [r.param.name for r in sens.ranking()]
    rss_model = tol.rss([a.growth_model_um for a in alloc])
    rss_traced = tol.rss([a.growth_traced_um for a in alloc])
    by = {a.name: a for a in alloc}
    params = []
    for r in sens.rows:
        a = by[r.param.name]
        lw, qw = r.worst_fit()
        lm, qm = r.mean_fit()
        params.append(
            {
                "name": r.param.name,
                "kind": r.param.kind,
                "surface": r.param.surface,
                "unit": r.param.unit,
                "nominal": r.nominal,
                "step": r.step,
                "rank": ranking.index(r.param.name) + 1,
                "offsets": r.deltas,
                "rms_fields_um": r.fields,
                "rms_worst_um": r.worst,
                "rms_mean_um": r.mean,
                "d_worst_step_um": r.d_worst_step,
                "d_mean_step_um": r.d_mean_step,
                "worst_fit": {"linear_um_per_unit": lw, "quadratic_um_per_unit2": qw},
                "mean_fit": {"linear_um_per_unit": lm, "quadratic_um_per_unit2": qm},
                "field_models": {"linear_um_per_unit": r.a, "quadratic_um_per_unit2": r.b},
                "fit_rms_um": r.fit_rms_um,
                "failed": r.failed,
                "given": {"min": r.param.min, "max": r.param.max},
                "share_um": a.share_um,
                "tolerance": a.tolerance,
                "capped": a.capped,
                "cap": a.cap,
                "proposed": {"min": a.lo, "max": a.hi},
                "growth_model_um": a.growth_model_um,
                "growth_traced_um": a.growth_traced_um,
                "traced_ends_um": a.traced_ends_um,
                "traced_failed": a.traced_failed,
            }
        )
    y_model = float((tol.model_worst(sens, mc.values) <= spec_um).mean()) if mc is not None else None
    doc = {
        "lens": lens.name,
        "lens_source": lens.source,
        "space": str(space_path),
        "fields_deg": sens.fields_deg,
        "rings": rings,
        "arms": arms,
        "apertures": apertures,
        "step_scale": step_scale,
        "default_steps": tol.DEFAULT_STEPS,
        "offsets_in_steps": tol.OFFSETS,
        "nominal": {"rms_fields_um": sens.nominal_fields, "worst_rms_um": w0, "mean_rms_um": sens.nominal_mean},
        "budget_um": budget_um,
        "spec_um": spec_um,
        "share_um": alloc[0].share_um,
        "rss_predicted_growth_um": {"model": rss_model, "traced": rss_traced},
        "ranking": ranking,
        "parameters": params,
        "proposed_space": str(out / "proposed.toml"),
        "monte_carlo": None
        if mc is None
        else {
            "space": mc_space,
            **mc.summary(),
            "yield_model": y_model,
            "worst_rms_um": mc.worst,
            "values": mc.values,
            "failed_index": mc.failed_index,
        },
        "warnings": warnings,
    }
    write_record_atomic(out / "tolerance.json", doc, indent=1)
    summary = {
        "lens": lens.name,
        "space": str(space_path),
        "out": str(out),
        "apertures": apertures,
        "nominal_rms_um": w0,
        "budget_um": budget_um,
        "spec_um": spec_um,
        "share_um": alloc[0].share_um,
        "rss_predicted_growth_um": rss_model,
        "most_sensitive": ranking[:3],
        "capped": [a.name for a in alloc if a.capped],
        "mc_space": mc_space,
        "yield": mc.yield_ if mc else None,
        "yield_stderr": mc.yield_stderr if mc else None,
        "n_mc": mc.n if mc else 0,
        "n_failed": mc.n_failed if mc else 0,
        "yield_model": y_model,
        "mc_rejected": mc.sampling["rejected"] if mc else 0,
        "mc_worst_rms_p50_um": mc.percentiles()["p50"] if mc else None,
        "mc_worst_rms_p95_um": mc.percentiles()["p95"] if mc else None,
    }
    click.echo(dumps(summary))
