"""``optix surrogate train DATA --out DIR`` and ``optix surrogate eval MODEL DATA`` (docs/surrogate.md)."""

from __future__ import annotations

from pathlib import Path

import click

from ._common import SEED, THREADS, FiniteFloatRange, device_option, dumps, friendly_errors

DATA = click.Path(file_okay=False, exists=True, path_type=Path)


@click.group("surrogate")
def surrogate():
    """The optics surrogate (paper Sec. 4.1): lens parameters + field -> RGB PSF and vignetting."""


@surrogate.command("train")
@click.argument("data", type=DATA)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Run directory: surrogate.pt, state.pt (resume), train.json, tb/ (TensorBoard).",
)
@click.option(
    "--psf",
    type=click.Choice(["psf_sensor", "psf"]),
    default="psf_sensor",
    show_default=True,
    help="Train on the sensor-pitch PSFs or the super-resolved ones.",
)
@click.option(
    "--bin",
    "bin_",
    type=click.IntRange(1, 64),
    default=1,
    show_default=True,
    help="Sum bin x bin pixel blocks of the PSFs first (a coarser pitch, same window).",
)
@click.option("--hidden", type=click.IntRange(1, 16384), default=256, show_default=True, help="MLP width.")
@click.option("--depth", type=click.IntRange(1, 64), default=4, show_default=True, help="MLP layers.")
@click.option(
    "--base-channels",
    type=click.IntRange(1, 4096),
    default=64,
    show_default=True,
    help="Decoder channels at its coarsest level (halved at each upsampling).",
)
@click.option("--n-up", type=click.IntRange(0, 6), default=2, show_default=True, help="Decoder x2 upsamplings.")
@click.option("--steps", type=click.IntRange(1, 10_000_000), default=20000, show_default=True)
@click.option(
    "--minutes",
    type=FiniteFloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Training-time budget over all resumed runs; the learning rate anneals over it (0: none).",
)
@click.option(
    "--batch", type=click.IntRange(1, 65536), default=256, show_default=True, help="(design, field) samples per step."
)
@click.option("--lr", type=FiniteFloatRange(min=0, min_open=True), default=2e-3, show_default=True)
@click.option(
    "--val-designs",
    type=click.IntRange(0, 10_000_000),
    default=256,
    show_default=True,
    help="Designs held out of training for validation (and for `eval` on this dataset).",
)
@click.option(
    "--max-designs",
    type=click.IntRange(0, 100_000_000),
    default=0,
    show_default=True,
    help="Use only the first N designs of DATA (0: all).",
)
@click.option(
    "--val-every",
    type=click.IntRange(1, 10_000_000),
    default=500,
    show_default=True,
    help="Validate and write the checkpoints every N steps.",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--threads", type=THREADS, default=0, help="torch CPU threads (0: default).")
@device_option
@click.option(
    "--init",
    default="",
    help="Start from this surrogate's weights (a checkpoint, a run directory or "
    "`paper-triplet-v1`): a fine-tune, e.g. after the dataset was regenerated. Same architecture.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@friendly_errors
def train_cmd(data, out_dir, bin_, as_json, **kw):
    """Train a surrogate on the PSF dataset DATA (`optix dataset`). Running the same command
    again resumes from DIR/state.pt (a larger --steps or --minutes continues a finished run).
    `torchrun --nproc_per_node N -m optix_e2e surrogate train ...` trains on N processes
    (DistributedDataParallel; --batch is the global batch; docs/distributed.md)."""
    from .. import parallel
    from ..surrogate.train import config_from_options, train

    cfg = config_from_options(bin=bin_, **kw)
    try:
        summary = train(data, out_dir, cfg, log=lambda m: click.echo(m, err=True))
    finally:
        parallel.teardown()
    if summary is None:  # not rank 0 of a torchrun run: rank 0 reports
        return
    if as_json:
        click.echo(dumps({k: v for k, v in summary.items() if k != "history"}))
        return
    v = summary["final_val"] or {}
    click.echo(
        f"{summary['steps_done']} steps in {summary['seconds']:.0f} s on {summary['device']}; validation "
        f"PSF rel L1 median {v.get('psf_rel_l1_median', float('nan')):.2%}, vignetting error median "
        f"{v.get('vignetting_abs_err_median', float('nan')):.4f}"
    )
    click.echo(f"wrote {out_dir / 'surrogate.pt'}, {out_dir / 'train.json'}, TensorBoard logs in {out_dir / 'tb'}")


@surrogate.command("eval")
@click.argument("model")
@click.argument("data", type=DATA)
@click.option(
    "--max-designs",
    type=click.IntRange(0, 100_000_000),
    default=0,
    show_default=True,
    help="Score at most N held-out designs (0: all).",
)
@click.option(
    "--png",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="PNG grid of predicted vs exact PSFs (default: OUT/grid.png with --out).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Write eval.json and grid.png here.",
)
@device_option
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
@friendly_errors
def eval_cmd(model, data, max_designs, png, out_dir, device, as_json):
    """Score MODEL (a checkpoint, a training directory, or `paper-triplet-v1` for the shipped
    surrogate) on DATA's held-out designs: PSF relative L1/L2, Strehl, encircled-energy and
    vignetting errors, per field and overall."""
    from ..device import resolve_device
    from ..surrogate.checkpoint import OpticsSurrogate, resolve
    from ..surrogate.evaluate import evaluate

    dev = resolve_device(device)
    if out_dir is not None:  # before any work: never into another command's folder or over its eval.json
        from ..io import claim_out_dir, json_holds

        def own(folder: Path) -> bool:  # isp eval writes an eval.json too
            return json_holds(folder / "eval.json", "psf_rel_l1_median")

        claim_out_dir(out_dir, "surrogate evaluation", {"eval.json", "grid.png"}, own=own)
    m = OpticsSurrogate.load(model).to(dev)
    if png is None and out_dir is not None:
        png = out_dir / "grid.png"
    res = evaluate(m, data, max_designs=max_designs or None, png=png)
    res["model"] = str(resolve(model))
    res["device"] = str(dev)  # where the network predicted (the metrics are computed on the CPU)
    if out_dir is not None:
        from ..io import write_text_atomic

        out_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out_dir / "eval.json", dumps(res, indent=2))
    if as_json:
        click.echo(dumps(res))
        return
    click.echo(
        f"{res['model']} on {res['n_designs']} held-out designs ({res['n_psfs']} PSFs): "
        f"PSF rel L1 median {res['psf_rel_l1_median']:.2%}, rel L2 {res['psf_rel_l2_median']:.2%}, "
        f"Strehl {res['strehl_rel_err_median']:.2%}, EE {res['ee_abs_err_median']:.4f}, "
        f"vignetting {res['vignetting_abs_err_median']:.4f}"
    )
    for row in res["per_field"]:
        click.echo(
            f"  {row['field_deg']:6.2f} deg: L1 {row['psf_rel_l1']['median']:.2%}  "
            f"vignetting {row['vignetting_abs_err']['median']:.4f}"
        )
