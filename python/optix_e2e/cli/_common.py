"""Helpers shared by the subcommands: lens loading, one-line errors, JSON output."""

from __future__ import annotations

import functools
import json
import math

import click
import numpy as np

from ..lens.glass import GlassError
from ..lens import Lens
from ..lens.text import printable
from ..lens.prescription import PrescriptionError

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
SEED = click.IntRange(0, 2 ** 63 - 1)  # what numpy and torch generators accept
THREADS = click.IntRange(0, 1024)  # parallel.MAX_THREADS: torch aborts when asked for tens of thousands


def _engine_errors() -> tuple[type[BaseException], ...]:
    try:
        from .. import _engine
    except ImportError:
        return ()
    return (_engine.EngineError,)


def friendly_errors(fn):
    """Turn expected failures into a one-line ``Error: ...`` and exit status 1."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except click.ClickException:
            raise
        except (PrescriptionError, GlassError, ValueError, OSError, RuntimeError, ImportError) as exc:
            raise click.ClickException(_one_line(exc)) from None
        except _engine_errors() as exc:
            raise click.ClickException(f"engine: {type(exc).__name__}: {_one_line(exc)}") from None

    return wrapper


def _one_line(exc: BaseException) -> str:
    return printable(" ".join(str(exc).split())) or type(exc).__name__


def load_lens(spec: str) -> Lens:
    return Lens.load(spec)


def to_jsonable(obj):
    """Numpy scalars/arrays -> Python; non-finite floats -> None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def dumps(obj, **kw) -> str:
    return json.dumps(to_jsonable(obj), allow_nan=False, **kw)
