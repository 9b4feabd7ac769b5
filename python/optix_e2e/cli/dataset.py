"""``optix dataset SPACE -n N --seed S --out DIR``, ``optix dataset verify DIR`` and
``optix dataset merge OUT DIR...`` (docs/dataset.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ._common import SEED, FiniteFloatRange, dumps, friendly_errors


class _DefaultToGenerate(click.Group):
    """``optix dataset SPACE ...`` runs the ``generate`` subcommand; ``verify`` and
    ``merge`` are subcommands of their own."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and args[0] not in ("-h", "--help"):
            args = ["generate", *args]
        return super().parse_args(ctx, args)


@click.group("dataset", cls=_DefaultToGenerate)
def dataset():
    """PSF datasets: `optix dataset SPACE -n N --seed S --out DIR` generates (or resumes);
    `optix dataset verify DIR` checks; `optix dataset merge OUT DIR...` combines shard ranges."""


@dataset.command("generate")
@click.argument("space_spec", metavar="SPACE")
@click.option("-n", "n", type=click.IntRange(1, 10_000_000), required=True, help="Designs to sample.")
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True)
@click.option(
    "--fields",
    "n_fields",
    type=click.IntRange(0, 1000),
    default=13,
    show_default=True,
    help="K field positions, uniform along +y from the axis to the lens's full field; 0: auto, the "
    "fewest whose linear interpolation meets --accuracy on the base design (manifest 'auto').",
)
@click.option(
    "--window-um",
    type=FiniteFloatRange(min=0, min_open=True),
    default=128.0,
    show_default=True,
    help="Super-resolved PSF window.",
)
@click.option(
    "--pixel-um",
    type=FiniteFloatRange(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="Super-resolved PSF pitch.",
)
@click.option(
    "--sensor-pixel-um",
    type=FiniteFloatRange(min=0, min_open=True),
    default=5.86,
    show_default=True,
    help="Pitch of the sensor-pitch PSFs.",
)
@click.option("--pupil-samples", type=click.IntRange(4, 4096), default=64, show_default=True)
@click.option(
    "--psf-method",
    type=click.Choice(["auto", "fft", "huygens", "geometric"]),
    default="auto",
    show_default=True,
    help="auto: per PSF, the cheapest method and sampling predicted to meet --accuracy; each "
    "choice is recorded in the shard's meta.json (psf_methods) and counted by verify.",
)
@click.option(
    "--accuracy",
    type=FiniteFloatRange(min=0, min_open=True),
    default=0.02,
    show_default=True,
    help="method auto: target relative L1 error of each monochromatic PSF.",
)
@click.option("--aiming", type=click.Choice(["paraxial", "real"]), default="paraxial", show_default=True)
@click.option(
    "--channels",
    type=click.Choice(["lens", "rgb", "auto"]),
    default="lens",
    show_default=True,
    help="lens: the lens's three wavelengths as R, G, B; rgb: three wavelengths per channel; auto: "
    "per channel the fewest band wavelengths meeting --accuracy on the base design (manifest 'auto').",
)
@click.option(
    "--apertures",
    type=click.Choice(["auto", "fixed"]),
    default="auto",
    show_default=True,
    help="auto: no clear apertures (every surface passes the beam); fixed: the base lens's "
    "(mechanical vignetting), the stop's excepted. The aperture is the lens's f-number/EPD.",
)
@click.option(
    "--focus",
    type=click.Choice(["best", "paraxial", "fixed"]),
    default="best",
    show_default=True,
    help="Image plane of each design: best (least RMS spot over the fields), paraxial, or fixed (the base lens's).",
)
@click.option(
    "--focus-within",
    type=click.Choice(["bfd", "none"]),
    default=None,
    help="bfd: the focus puts no image plane nearer the last surface than the space's back-focus "
    "limit (its [constraints] min_bfd; such a design is imaged at the limit, said in the shard's "
    "warnings); none: wherever it falls (a plane inside the last surface fails the design). "
    "Default: bfd for a new dataset, the dataset's own rule when DIR holds one (none before 2026-11-28).",
)
@click.option("--shard-size", type=click.IntRange(1, 100_000), default=64, show_default=True)
@click.option("--sampling", type=click.Choice(["sobol", "uniform", "lhs"]), default="sobol", show_default=True)
@click.option(
    "--shards",
    "shard_range",
    default=None,
    help="Only these shards: A:B (B exclusive) or K; for several processes on one dataset.",
)
@click.option(
    "--dask",
    "dask_address",
    metavar="ADDRESS",
    default=None,
    help="Run the missing shards as tasks on a Dask cluster: a scheduler address (tcp://host:8786), "
    "a scheduler file (*.json), or local:N to start N local worker processes of 1 thread. DIR "
    "must be on storage every worker sees at the same path.",
)
@friendly_errors
def generate_cmd(
    space_spec,
    n,
    seed,
    out_dir,
    n_fields,
    window_um,
    pixel_um,
    sensor_pixel_um,
    pupil_samples,
    psf_method,
    accuracy,
    aiming,
    channels,
    apertures,
    focus,
    focus_within,
    shard_size,
    sampling,
    shard_range,
    dask_address,
):
    """Sample N designs from SPACE (a TOML space or a bundled lens's name) and write their
    RGB PSFs at K fields, shard by shard, into DIR.  Running the same command again resumes."""
    from ..dataset import DatasetSettings, generate
    from ..dataset.layout import read_json

    if focus_within is None:  # a new dataset's rule, or the one DIR's dataset was made with
        man = Path(out_dir) / "manifest.json"
        held = read_json(man, "manifest") if man.is_file() else None
        settings = held.get("settings") if isinstance(held, dict) else None
        focus_within = DatasetSettings.recorded(settings, "focus_within") if isinstance(settings, dict) else "bfd"
    s = DatasetSettings(
        n_fields=n_fields,
        window_um=window_um,
        pixel_um=pixel_um,
        sensor_pixel_um=sensor_pixel_um,
        pupil_samples=pupil_samples,
        psf_method=psf_method,
        accuracy=accuracy,
        aiming=aiming,
        channels=channels,
        apertures=apertures,
        focus=focus,
        focus_within=focus_within,
        shard_size=shard_size,
        sampling=sampling,
    )
    rep = generate(
        space_spec, n, seed, out_dir, s, shards=shard_range, log=lambda m: click.echo(m, err=True), dask=dask_address
    )
    click.echo(dumps(rep.to_json()))
    if rep.shard_errors:
        ks = ", ".join(str(e["shard"]) for e in rep.shard_errors)
        raise click.ClickException(
            f"{len(rep.shard_errors)} shard(s) failed on the cluster ({ks}; errors in the "
            f"JSON above); the same command again redoes them"
        )


@dataset.command("verify")
@click.argument("root", metavar="DIR", type=click.Path(file_okay=False, exists=True))
@click.option("--no-hashes", is_flag=True, help="Skip the sha256 checks (shapes and values only).")
@friendly_errors
def verify_cmd(root, no_hashes):
    """Check every shard of DIR against the manifest; print one JSON line (n_designs,
    n_failed, digest, problems).  Exit status 1 when a shard is missing or damaged."""
    from ..dataset import verify

    rep = verify(root, check_hashes=not no_hashes)
    click.echo(dumps(rep))
    if not rep["ok"]:
        for p in rep["problems"]:
            click.echo(f"problem: {p}", err=True)
        if rep["missing_shards"]:
            click.echo(f"missing shards: {rep['missing_shards']}", err=True)
        sys.exit(1)


@dataset.command("merge")
@click.argument("out", type=click.Path(file_okay=False))
@click.argument("parts", nargs=-1, required=True, type=click.Path(file_okay=False, exists=True))
@friendly_errors
def merge_cmd(out, parts):
    """Copy the shards of PARTS (directories of one dataset, made by separate processes)
    into OUT."""
    from ..dataset.merge import merge

    click.echo(dumps(merge(out, parts)))
