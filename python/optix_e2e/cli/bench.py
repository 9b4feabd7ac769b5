"""``optix bench accuracy``: speed against accuracy of every PSF method and setting."""

from __future__ import annotations

import click

from ._common import dumps, friendly_errors


@click.group("bench")
def bench():
    """Benchmarks that write their measurements as files."""


@bench.command("accuracy")
@click.option(
    "--lens",
    "lenses",
    multiple=True,
    metavar="LENS",
    help="Lens (repeatable; default: the bundled cooke-f50, paper-triplet, double-gauss-f5).",
)
@click.option("--quick", is_flag=True, help="Fewer settings, fields and wavelengths, a looser reference (a smoke run).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output directory.")
@friendly_errors
def accuracy(lenses, quick, out_dir):
    """Each PSF method and setting (geometric with N rays across; FFT at N pupil samples and
    grid padding Q; the fast FFT; Huygens at N) against a converged Huygens reference at
    the axis, mid and edge field and each lens wavelength; wavelengths per colour channel;
    field samples K with interpolation.  Writes rows.csv, summary.csv (Pareto front
    marked), sampling.csv, accuracy.json and the charts speed_accuracy.png and sampling.png
    into OUT; prints accuracy.json."""
    from ..accuracy.run import DEFAULT_LENSES, run
    from ..io import claim_out_dir

    claim_out_dir(
        out_dir,
        "accuracy bench",
        {"rows.csv", "summary.csv", "sampling.csv", "speed_accuracy.png", "sampling.png", "accuracy.json"},
    )
    rep = run(out_dir, lenses or DEFAULT_LENSES, quick=quick)
    click.echo(dumps(rep))
