"""``optix design TASK --out DIR``: an end-to-end camera design (paper Sec. 6.1, Alg. 1)."""

from __future__ import annotations

from pathlib import Path

import click

from ._common import DEVICE_HELP, PRECISION_HELP, SEED, THREADS, dumps, friendly_errors


class TaskName(click.ParamType):
    """A registered task's name (tasks/registry.py), checked when the command runs: the registry
    (and torch with it) is imported then, not when `optix` starts."""

    name = "task"

    def convert(self, value, param, ctx):
        from ..errors import InputError
        from ..tasks import plugin

        try:
            return plugin(value).name
        except InputError as err:
            self.fail(str(err), param, ctx)


class DesignCommand(click.Command):
    """`optix design --help` lists every registered task with its plugin's help line."""

    def format_help_text(self, ctx, formatter):
        super().format_help_text(ctx, formatter)
        from ..tasks import plugins

        with formatter.section("Tasks"):
            formatter.write_dl([(p.name, p.help) for p in plugins()])


@click.command("design", cls=DesignCommand)
@click.argument("task", type=TaskName())
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    required=True,
    help="Run directory: config.json, checkpoints (resume), tb/ (TensorBoard), results.json, "
    "panels.png, psf_*.png, lens/, report/.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False),
    help="TOML file overriding any setting of the budget by name (optix_e2e.camera_design.config).",
)
@click.option(
    "--optimizer",
    type=click.Choice(["alg1", "vanilla"]),
    default=None,
    help="Alg. 1 (alternating, proximal; default) or one Adam over everything (the paper's vanilla).",
)
@click.option(
    "--budget",
    type=click.Choice(["smoke", "quick", "full"]),
    default=None,
    help="smoke: seconds (tests); quick (the default): the main job; full: the figures we report.",
)
@click.option("--seed", type=SEED, default=None, help="Initialization, batches and noise (default 0).")
@click.option(
    "--surrogate",
    default=None,
    help="Optics surrogate: bundled name, checkpoint or run dir "
    "(default: paper-triplet-e2e; detection: paper-triplet-detect).",
)
@click.option(
    "--images",
    type=click.Path(exists=True, file_okay=False),
    default=None,
    help="A folder of your images, mixed into the training scenes.",
)
@click.option(
    "--photos",
    type=click.Path(exists=True, file_okay=False),
    default=None,
    help="A prepared photo corpus (`optix scenes photos prepare`): its photographs become most of the training scenes.",
)
@click.option(
    "--optics",
    type=click.Choice(["surrogate", "exact", "hybrid", "auto"]),
    default=None,
    help="The optics model in the loop: the exact engine with central-difference gradients (default, "
    "detection too but for its smoke budget), the surrogate, the surrogate checked and refined along the way, or auto "
    "(from the measured speed/accuracy trade-off; docs/optics-in-the-loop.md).",
)
@click.option(
    "--space",
    default=None,
    help="The space the lens moves in: a bundled space (e.g. paper-triplet-wide, the paper's Table 1 "
    "widths) or a TOML file over the surrogate's parameters and base lens (default: the surrogate's; "
    "detection at quick and full: paper-triplet-detect-wide). Needs --optics exact.",
)
@click.option(
    "--start",
    "optics_init",
    type=click.Choice(["nominal", "uniform"]),
    default=None,
    help="The lens's start: the nominal (default) or uniform at random in the space, drawn from --seed "
    "until manufacturable (the paper's Sec. 5.2).",
)
@click.option(
    "--test-photos",
    type=click.Path(exists=True, file_okay=False),
    multiple=True,
    help="A prepared test-split corpus (`optix scenes photos prepare kodak24 ...`; repeatable): every camera is "
    "also evaluated on it under docs/test-split.md's protocol (results.json test_split); a finished run is "
    "evaluated without training again.",
)
@click.option("--threads", type=THREADS, default=None, help="torch CPU threads (0: default).")
@click.option("--device", default=None, help=DEVICE_HELP + " [default: auto, or the config file's device]")
@click.option("--precision", default=None, type=click.Choice(["fp32", "bf16", "fp16"]), help=PRECISION_HELP)
@click.option("--quiet", is_flag=True, help="No progress bars.")
@friendly_errors
def design(
    task,
    out,
    config_file,
    optimizer,
    budget,
    seed,
    surrogate,
    images,
    photos,
    optics,
    space,
    optics_init,
    test_photos,
    threads,
    device,
    precision,
    quiet,
):
    """Optimize lens and processing together for TASK, against the nominal lens with its
    processing fine-tuned with as many updates per block, and evaluate both under the exact
    engine's PSFs on held-out images (the frame's positions the headline; centre, corner
    apart). Running the same command again resumes an interrupted run, with the settings it was
    made with (those given must match them).
    `torchrun --nproc_per_node N -m optix_e2e design ...` shares each training batch over N
    processes (gloo; the batch must divide by N; docs/distributed.md)."""
    from .. import parallel
    from ..camera_design.config import load_config
    from ..camera_design.run import run_design, summary_lines
    from ..device import resolve_device

    if device is not None:
        resolve_device(device)  # a GPU that is not there: one error naming --device
    cfg, given = load_config(
        budget,
        config_file,
        task=task,
        optimizer=optimizer,
        seed=seed,
        surrogate=surrogate,
        images=images,
        photos=photos,
        threads=threads,
        optics=optics,
        space=space,
        optics_init=optics_init,
        device=device,
        precision=precision,
    )
    try:
        res = run_design(
            cfg, Path(out), given=given, progress=not quiet, log=click.echo, test_photos=tuple(test_photos)
        )
    finally:
        parallel.teardown()
    if res is None:  # not rank 0 of a torchrun run: rank 0 reports
        return
    for line in summary_lines(cfg, res):
        click.echo(line)
    click.echo(
        f"results: {Path(out) / 'results.json'}  (lens: {Path(out) / res['lens_zmx']}, wall {res['wall_s']:.0f} s)"
    )
    click.echo(dumps({"results": str(Path(out) / "results.json"), "wall_s": res["wall_s"]}))
