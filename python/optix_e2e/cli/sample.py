"""``optix sample SPACE -n N --seed S --method ... --out designs.csv``."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ..io import write_record_atomic
from ..lens_design.constraints import Limits
from ..lens_design.sampling import APERTURE_RULES, METHODS, sample_designs, write_designs_csv
from ..lens_design.space import load_space
from ._common import FINITE, SEED, dumps, friendly_errors


def limit_options(fn):
    """--min-air-gap / --min-center / --min-edge / --min-bfd, overriding the space's own."""
    for name, what in (
        ("min-bfd", "back focal distance"),
        ("min-edge", "glass edge thickness"),
        ("min-center", "glass center thickness"),
        ("min-air-gap", "air gap (center and rim)"),
    ):
        fn = click.option(
            f"--{name}", type=FINITE, default=None, help=f"Minimum {what} (mm); default: the space's [constraints]."
        )(fn)
    return fn


@click.command("sample")
@click.argument("space_spec", metavar="SPACE")
@click.option("-n", "n", type=click.IntRange(1, 10_000_000), required=True, help="Designs to accept.")
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--method",
    type=click.Choice(METHODS),
    default="sobol",
    show_default=True,
    help="uniform (PCG64), scrambled Sobol' or Latin hypercube (scipy.stats.qmc).",
)
@click.option("--out", "out_path", type=click.Path(dir_okay=False), required=True, help="designs.csv")
@click.option(
    "--apertures",
    type=click.Choice(APERTURE_RULES),
    default="auto",
    show_default=True,
    help="How the designs will be traced (as `optix dataset generate --apertures`): each checked at its own "
    "clear apertures; base-lens: the base lens's for every design (datasets made before 2026-11-27).",
)
@limit_options
@friendly_errors
def sample(space_spec, n, seed, method, out_path, apertures, min_air_gap, min_center, min_edge, min_bfd):
    """Draw N manufacturable designs from SPACE (a TOML space file or a bundled lens name).

    Candidates failing a check are counted by reason; the summary (printed as JSON and
    written beside OUT as <stem>.summary.json) has the accepted, drawn and rejected counts.
    """
    from tqdm import tqdm

    space, base = load_space(space_spec)
    limits = Limits.from_dict(space.constraints, f"{space.source}: [constraints]").merged(
        min_air_gap=min_air_gap, min_center=min_center, min_edge=min_edge, min_bfd=min_bfd
    )
    bar = tqdm(total=n, unit="design", desc="sample", file=sys.stderr, dynamic_ncols=True)

    def progress(drawn, accepted):
        bar.update(accepted - bar.n)
        bar.set_postfix(drawn=drawn, refresh=False)

    try:
        res = sample_designs(
            space, base, n, seed=seed, method=method, limits=limits, progress=progress, apertures=apertures
        )
    finally:
        bar.close()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)  # like the other commands' --out
    write_designs_csv(out_path, space.names, res.values)
    summary = {"out": str(out_path), "lens": base.name, **res.summary()}
    write_record_atomic(Path(out_path).with_suffix(".summary.json"), summary)
    click.echo(dumps(summary))
