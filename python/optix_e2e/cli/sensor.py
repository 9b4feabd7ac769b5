"""``optix sensor ...``: the EMVA 1288 sensor model. ``sensor ptc``: photon-transfer analysis."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from ._common import SEED, FiniteFloatRange, dumps, friendly_errors


@click.group("sensor")
def sensor():
    """Differentiable EMVA 1288 sensor model (presets, photon transfer)."""


@sensor.command("ptc")
@click.option("--preset", default="imx249", show_default=True, help="Sensor preset (imx249, phone-1um).")
@click.option(
    "--exposure-s", type=FiniteFloatRange(min=0, min_open=True), default=None, help="Exposure time override (s)."
)
@click.option(
    "--gain", type=FiniteFloatRange(min=0, min_open=True), default=None, help="System gain K override (DN/e-)."
)
@click.option(
    "--low-light",
    "low_light",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Paper's low-light setting: exposure / FACTOR and gain x FACTOR (before other overrides).",
)
@click.option(
    "--temperature",
    "temperature_c",
    type=FiniteFloatRange(min=-273.15),
    default=None,
    help="Sensor temperature override (C).",
)
@click.option(
    "--levels",
    "n_levels",
    type=click.IntRange(10, 1000),
    default=50,
    show_default=True,
    help="Irradiance levels from dark to beyond saturation.",
)
@click.option(
    "--patch", type=click.IntRange(8, 4096), default=256, show_default=True, help="Flat-field patch size (px)."
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Directory for ptc.json and ptc.png.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the full result as JSON on stdout.")
@friendly_errors
def ptc(preset, exposure_s, gain, low_light, temperature_c, n_levels, patch, seed, out_dir, as_json):
    """Simulate an EMVA 1288 photon-transfer measurement and compare it with the preset.

    Prints gain K, dark noise and saturation capacity as measured from the simulated flat
    fields, with their relative errors against the preset (see the JSON's 'compared').
    """
    from tqdm import tqdm

    from ..sensor import get_preset, photon_transfer, save_ptc

    p = get_preset(preset)
    if low_light is not None:
        p = p.low_light(low_light)
    bar = tqdm(total=n_levels, unit="level", desc="ptc", file=sys.stderr, dynamic_ncols=True, delay=1.0)

    def progress(done, total):
        bar.update(done - bar.n)

    try:
        res = photon_transfer(
            p,
            exposure_s=exposure_s,
            gain=gain,
            temperature_c=temperature_c,
            n_levels=n_levels,
            patch=patch,
            seed=seed,
            progress=progress,
        )
    finally:
        bar.close()
    if out_dir is not None:
        res["files"] = save_ptc(res, out_dir)
    if as_json:
        click.echo(dumps(res))
        return
    click.echo(f"{res['preset']}: {res['n_levels']} levels, {res['pixels_per_frame']} {res['channel']} pixels/frame")
    for what, meas, ref, unit, err in (
        ("gain K", res["measured_gain_dn_per_e"], res["preset_gain_dn_per_e"], "DN/e-", res["gain_rel_err"]),
        ("dark noise", res["measured_dark_noise_e"], res["reference_dark_noise_e"], "e-", res["dark_noise_rel_err"]),
        ("saturation", res["measured_saturation_e"], res["reference_saturation_e"], "e-", res["saturation_rel_err"]),
    ):
        click.echo(f"  {what:<11} {meas:10.4g} {unit:<6} (preset {ref:.4g}, {100 * err:+.2f}%)")
    click.echo(f"  linearity error {res['linearity_error_pct']:.3f}%")
    for w in res["warnings"]:
        click.echo(f"  warning: {w}")
    if out_dir is not None:
        click.echo(f"  wrote {res['files']['json']} and {res['files']['png']}")
