"""``optix demo``: RGB PSFs of a lens across the field -> PNG grid + JSON summary."""

from __future__ import annotations

import time
from pathlib import Path

import click
import numpy as np
from tqdm import tqdm

from ..io import save_npy_atomic, write_record_atomic
from ._common import AIMING, FiniteFloatRange, friendly_errors, load_lens

MAX_PRINTED_WARNINGS = 8


def _channel_label(name: str, channel) -> str:
    wls = [w for w, _ in channel]
    span = f"{min(wls):g}-{max(wls):g} nm" if len(wls) > 1 else f"{wls[0]:g} nm"
    return f"{name} {span}"


def _collect_warnings(field_deg, rgb_diag, mono_diag) -> list[str]:
    """Engine warnings of one field, each labelled with its field and wavelength."""
    out = [f"{field_deg:g} deg: {w}" for w in rgb_diag.get("warnings", [])]
    for d in list(rgb_diag.get("per_wavelength", [])) + [mono_diag]:
        for w in d.get("warnings", []):
            line = f"{field_deg:g} deg, {d.get('wavelength_nm', 0):g} nm: {w}"
            if line not in out:
                out.append(line)
    return out


@click.command()
@click.option(
    "--lens",
    "lens_spec",
    default="cooke-f50",
    show_default=True,
    metavar="LENS",
    help="JSON prescription path or bundled lens name.",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("results/psf-demo"),
    show_default=True,
    help="Output folder (created; empty or a previous demo's).",
)
@click.option(
    "--n-fields",
    type=click.IntRange(1, 1000),
    default=5,
    show_default=True,
    help="Fields evenly spaced from the axis to the full field.",
)
@click.option(
    "--channels",
    type=click.Choice(["rgb", "lens"]),
    default="rgb",
    show_default=True,
    help="rgb: 3 wavelengths per channel with weights; lens: the lens's 3 wavelengths as R, G, B.",
)
@click.option("--method", type=click.Choice(["geometric", "fft", "huygens"]), default="fft", show_default=True)
@click.option("--pixel-um", type=FiniteFloatRange(min=0, min_open=True), default=1.0, show_default=True)
@click.option("--size", type=click.IntRange(8, 4096), default=128, show_default=True)
@click.option("--pupil-samples", type=click.IntRange(8, 4096), default=64, show_default=True)
@click.option(
    "--rings",
    type=click.IntRange(1, 100_000),
    default=128,
    show_default=True,
    help="Hexapolar rings per wavelength for the RMS spot.",
)
@click.option("--aiming", type=AIMING, default="paraxial", show_default=True)
@click.option("--log/--linear", "log", default=True, show_default=True, help="PNG intensity scale.")
@friendly_errors
def demo(lens_spec, out_dir, n_fields, channels, method, pixel_um, size, pupil_samples, rings, aiming, log):
    """RGB PSFs of a lens from the axis to the full field.

    Writes OUT/psf_grid.png (fields x channels + RGB composite), OUT/psfs.npy
    (fields, channels, size, size) and OUT/summary.json (first-order data, per-field RMS
    spot, Strehl, relative illumination, warnings, timings).
    """
    t_start = time.perf_counter()
    from ..io import claim_out_dir

    claim_out_dir(out_dir, "PSF demo", {"psfs.npy", "psf_grid.png", "summary.json"})
    lens_ = load_lens(lens_spec)
    chans = lens_.rgb_channels(channels)
    names = ["R", "G", "B"] if len(chans) == 3 else [f"C{i}" for i in range(len(chans))]
    labels = [_channel_label(n, c) for n, c in zip(names, chans)]
    fields = [float(f) for f in np.linspace(0.0, lens_.max_field_deg, n_fields)]
    out_dir.mkdir(parents=True, exist_ok=True)

    paraxial = lens_.paraxial()
    psf_kw = dict(method=method, pixel_um=pixel_um, size=size, pupil_samples=pupil_samples, aiming=aiming)
    stacks, rows, all_warnings = [], [], []
    timings = {"psf_rgb_s": 0.0, "spot_s": 0.0, "strehl_s": 0.0}
    for f in tqdm(fields, desc=f"{lens_.name} PSFs", unit="field"):
        t0 = time.perf_counter()
        psfs, rel_illum, diag = lens_.psf_rgb(f, chans, **psf_kw)
        t1 = time.perf_counter()
        spot = lens_.spot(f, rings=rings, aiming=aiming)
        t2 = time.perf_counter()
        _, mono = lens_.psf(f, lens_.primary_wavelength_nm, **psf_kw)
        t3 = time.perf_counter()
        timings["psf_rgb_s"] += t1 - t0
        timings["spot_s"] += t2 - t1
        timings["strehl_s"] += t3 - t2
        warnings = _collect_warnings(f, diag, mono)
        all_warnings += warnings
        stacks.append(np.asarray(psfs, dtype=np.float64))
        rows.append(
            {
                "field_deg": f,
                "rms_spot_um": spot["rms_um"],
                "relative_illumination": spot["relative_illumination"],
                "relative_illumination_per_channel": dict(zip(names, np.asarray(rel_illum).tolist())),
                "strehl_primary": mono.get("strehl"),
                "warnings": warnings,
                "time_s": {"psf_rgb": t1 - t0, "spot": t2 - t1, "strehl": t3 - t2},
                "psf_rgb_diagnostics": diag,
            }
        )

    t0 = time.perf_counter()
    grid = np.stack(stacks)
    save_npy_atomic(out_dir / "psfs.npy", grid)
    from ..plotting import save_psf_grid

    save_psf_grid(
        out_dir / "psf_grid.png",
        grid,
        fields,
        pixel_um,
        labels,
        title=f"{lens_.name}: {method} PSFs",
        log=log,
        row_notes=[f"RMS {r['rms_spot_um']:.1f} um, RI {r['relative_illumination']:.2f}" for r in rows],
    )
    timings["plot_s"] = time.perf_counter() - t0
    timings["total_s"] = time.perf_counter() - t_start

    summary = {
        "lens": lens_.name,
        "source": lens_.source,
        "settings": {
            **psf_kw,
            "rings": rings,
            "channels": [[list(p) for p in c] for c in chans],
            "channel_labels": labels,
            "log_png": log,
        },
        "paraxial": paraxial,
        "fields": rows,
        "warnings": all_warnings,
        "timings": timings,
        "files": {"psf_grid_png": "psf_grid.png", "psfs_npy": "psfs.npy"},
    }
    write_record_atomic(out_dir / "summary.json", summary, indent=1)
    click.echo(
        f"wrote {out_dir / 'psf_grid.png'}, {out_dir / 'psfs.npy'}, {out_dir / 'summary.json'} "
        f"({len(fields)} fields x {len(chans)} channels, {timings['total_s']:.2f} s, "
        f"{len(all_warnings)} warning(s))"
    )
    for w in all_warnings[:MAX_PRINTED_WARNINGS]:
        click.echo(f"warning: {w}", err=True)
    if len(all_warnings) > MAX_PRINTED_WARNINGS:
        click.echo(
            f"... and {len(all_warnings) - MAX_PRINTED_WARNINGS} more warning(s) in {out_dir / 'summary.json'}",
            err=True,
        )
