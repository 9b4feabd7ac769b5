"""Zemax OpticStudio ``.zmx`` import and export (sequential lenses); see docs/zemax.md.

:func:`read_zmx` turns a file into our JSON prescription (docs/lens-format.md) plus a
report of what was ignored; :func:`write_zmx` / :func:`zmx_text` go the other way.
Nothing is dropped silently: a keyword either maps onto the prescription, is listed in
:attr:`ZemaxImport.ignored` (display / bookkeeping only, see ``IGNORED``), or raises a
:class:`ZemaxError` that names the file, the line and the keyword.  Unknown glass is an
error with near matches, never a substituted index.
"""

from __future__ import annotations

from .common import ZemaxError, ZemaxImport
from .numbers import _curv, _from_um, _radius, _to_um  # noqa: F401 (used by the tests)
from .reader import parse_zmx, read_zmx
from .writer import write_zmx, zmx_text

__all__ = ["ZemaxError", "ZemaxImport", "read_zmx", "parse_zmx", "write_zmx", "zmx_text"]
