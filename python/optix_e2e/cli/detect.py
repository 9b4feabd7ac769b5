"""``optix detect train DATA --out RUN`` and ``optix detect eval RUN DATA``: the detector (issue 19)."""

from __future__ import annotations

import click

from ._common import SEED, THREADS, FiniteFloatRange, device_option, dumps, friendly_errors, precision_option


@click.group("detect")
def detect():
    """The street-scene detector: train it on a COCO folder, measure its mAP on another."""


@detect.command("train")
@click.argument("data", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    required=True,
    help="Run directory: detector.pt (resumable), history.csv, tb/.",
)
@click.option("--steps", type=click.IntRange(1, 10_000_000), default=4000, show_default=True)
@click.option(
    "--minutes",
    type=FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Stop after this much training time (the learning rate anneals over it).",
)
@click.option("--batch", type=click.IntRange(1, 256), default=8, show_default=True)
@click.option("--lr", type=FiniteFloatRange(min=0, min_open=True), default=2e-3, show_default=True)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option(
    "--dim",
    type=FiniteFloatRange(min=0, max=1, min_open=True),
    default=1.0,
    show_default=True,
    help="Darken each training image by a log-uniform factor in [DIM, 1] in linear light (dusk "
    "exposures; 1: as stored).",
)
@click.option(
    "--noise",
    type=FiniteFloatRange(min=0, max=1),
    default=0.0,
    show_default=True,
    help="The fraction of training images given the design run's sensor noise at a dusk exposure "
    "(photon and read noise of the IMX249; tasks/detector_train.py:sensor_noise).",
)
@click.option("--threads", type=THREADS, default=0, help="torch CPU threads (0: default).")
@device_option
@precision_option
@click.option("--quiet", is_flag=True)
@friendly_errors
def train(data, out, steps, minutes, batch, lr, seed, dim, noise, threads, device, precision, quiet):
    """Train the detector on DATA (images/ + annotations.json, e.g. from `optix scenes street`)."""
    from ..parallel import set_threads
    from ..tasks.detector_train import train_detector

    set_threads(threads)
    click.echo(
        dumps(
            train_detector(
                data,
                out,
                steps=steps,
                minutes=minutes,
                batch=batch,
                lr=lr,
                seed=seed,
                dim=dim,
                noise=noise,
                device=device,
                precision=precision,
                progress=not quiet,
                log=click.echo,
            )
        )
    )


@detect.command("eval")
@click.argument("run", type=click.Path(exists=True))
@click.argument("data", type=click.Path(exists=True, file_okay=False))
@click.option("--threads", type=THREADS, default=0, help="torch CPU threads (0: default).")
@device_option
@friendly_errors
def evaluate(run, data, threads, device):
    """mAP@[.5:.95] and mAP@0.5 of the detector in RUN on DATA (and in its dark regions). One JSON line."""
    from ..device import resolve_device
    from ..parallel import set_threads
    from ..tasks.detector_train import evaluate_detector, load_detector

    set_threads(threads)
    dev = resolve_device(device)
    model, ck = load_detector(run)
    res = evaluate_detector(model.to(dev), data)
    click.echo(dumps({**res, "steps": ck.get("step"), "train_wall_s": ck.get("wall_s"), "device": str(dev)}))


@detect.command("tune")
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder: detector.pt, tune.json, history.csv, tune_state.pt (resumable).",
)
@click.option("--steps", type=click.IntRange(1, 1_000_000), default=1500, show_default=True)
@click.option(
    "--budget",
    type=click.Choice(["quick", "full"]),
    default="quick",
    show_default=True,
    help="The design budget whose detection settings (space, crop, batch, detector rate) it uses.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    help="A design config file (TOML): its detection settings, e.g. the start detector.",
)
@click.option("--scenes", type=click.IntRange(0, 10_000), default=100, show_default=True, help="Validation scenes.")
@click.option(
    "--threads",
    type=THREADS,
    default=None,
    help="torch CPU threads (0: default). Set it here or in the config file, not both.",
)
@click.option("--quiet", is_flag=True)
@friendly_errors
def tune(out, steps, budget, config_file, scenes, threads, quiet):
    """Tune the start detector and the hardware ISP behind the nominal camera at dusk (the
    paper's fine-tuned pipeline): the nominal lens's engine PSFs and the sensor fixed; the ISP,
    from its default settings, and the detector trained jointly on the task's loss, on the CPU.
    Writes OUT/detector.pt (with the tuned ISP) for a design run's `detector` setting and
    isp_init = "detector"."""
    from ..camera_design.config import make_config
    from ..camera_design.detector_tuning import tune_start_detector

    cfg = make_config(budget, config_file, task="detection", threads=threads).check()
    click.echo(dumps(tune_start_detector(cfg, out, steps, scenes=scenes, progress=not quiet, log=click.echo)))
