"""The package's errors: one base class, two kinds.

``OptixError`` is the base of every error this package raises on purpose. The command line
(``cli/_common.friendly_errors``) prints these as one ``Error: ...`` line, with the engine's own
``EngineError`` family (raised by the Rust extension, ``optix_e2e.engine``) and ``OSError``
(a file that cannot be read or written); anything else is a bug and shows as one, traceback
included.

- ``InputError`` (a ``ValueError``): something the user gave is wrong: a file, a setting, an
  option, a lens, a dataset. The message names it (file, line, surface, parameter).
- ``RunError`` (a ``RuntimeError``): a run cannot go on although its inputs were read: training
  diverged, a state on disk is damaged or belongs to another run, a worker is unreachable.

The package's named errors (``PrescriptionError``, ``ZemaxError``, ``DatasetError``, ...)
subclass one of the two. This module imports nothing: every layer may use it.
"""

from __future__ import annotations

__all__ = ["OptixError", "InputError", "RunError"]


class OptixError(Exception):
    """Base of every error optix_e2e raises on purpose."""


class InputError(OptixError, ValueError):
    """Something the user gave (file, setting, option, lens, data) is wrong; the message names it."""


class RunError(OptixError, RuntimeError):
    """A run cannot go on (diverged, damaged or foreign state, unreachable worker)."""
