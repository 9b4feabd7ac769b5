"""Helpers shared by the subcommands: lens loading, one-line errors, JSON output."""

from __future__ import annotations

import functools
import math

import click

from ..engine import EngineError
from ..errors import OptixError
from ..io import dumps, release_out_dirs, to_jsonable  # noqa: F401  (dumps, to_jsonable: the subcommands' strict JSON)
from ..lens import Lens
from ..lens.text import printable

AIMING = click.Choice(["paraxial", "real"])


class FiniteFloatRange(click.FloatRange):
    """``click.FloatRange`` that also refuses nan and inf, which click lets through."""

    name = "finite float range"

    def convert(self, value, param, ctx):
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


FINITE = FiniteFloatRange()
SEED = click.IntRange(0, 2**63 - 1)  # what numpy and torch generators accept
THREADS = click.IntRange(0, 1024)  # parallel.MAX_THREADS: torch aborts when asked for tens of thousands


DEVICE_HELP = "Where the torch stages run: auto (CUDA when present), cpu, cuda, cuda:K."


def device_option(fn):
    """``--device auto|cpu|cuda|cuda:K`` (optix_e2e.device.resolve_device; auto: CUDA when present)."""
    return click.option("--device", default="auto", show_default=True, help=DEVICE_HELP)(fn)


PRECISION_HELP = (
    "The networks' arithmetic: fp32 (default), or bf16 / fp16 autocast for the ISP net, the ISP proxy and the "
    "detector; optics, sensor, losses and metrics stay float32 (fp16 with a gradient scaler)."
)


def precision_option(fn):
    """``--precision fp32|bf16|fp16`` (optix_e2e.precision; the networks only)."""
    return click.option(
        "--precision",
        type=click.Choice(["fp32", "bf16", "fp16"]),
        default="fp32",
        show_default=True,
        help=PRECISION_HELP,
    )(fn)


def friendly_errors(fn):
    """Turn the package's own errors (``errors.OptixError``), the engine's (``EngineError``) and
    the operating system's (a file that cannot be read or written) into one ``Error: ...`` line
    and exit status 1. Anything else is a bug and propagates as one, traceback included."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except click.ClickException:
            raise
        except (OptixError, OSError) as exc:
            raise click.ClickException(_one_line(exc)) from None
        except EngineError as exc:
            raise click.ClickException(f"engine: {type(exc).__name__}: {_one_line(exc)}") from None
        finally:
            release_out_dirs()  # the folders the command held (io.hold_out_dir)

    return wrapper


def _one_line(exc: BaseException) -> str:
    return printable(" ".join(str(exc).split())) or type(exc).__name__


def load_lens(spec: str) -> Lens:
    return Lens.load(spec)
