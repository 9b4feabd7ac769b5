"""Exact number conversions for .zmx round trips: Zemax stores curvatures (CURV) and
wavelengths in micrometres, and 1/(1/R) is not always R in floating point, so the
reader picks the shortest decimal that the writer maps to the value read."""

from __future__ import annotations

import math


def _neighbours(x: float, k: int = 4):
    yield x
    lo = hi = x
    for _ in range(k):
        lo, hi = math.nextafter(lo, -math.inf), math.nextafter(hi, math.inf)
        yield lo
        yield hi


def _exact(target: float, x0: float, back) -> float:
    """An x near x0 with back(x) == target, so write-then-read returns ``target`` exactly."""
    for x in _neighbours(x0):
        if back(x) == target:
            return x
    return x0


def _shortest(raw: float, written: float, forward) -> float:
    """The shortest decimal near ``raw`` that the writer's ``forward`` maps to ``written``.
    Not every double radius has a double curvature whose reciprocal gives it back, so the
    reader picks the value a person would have typed: JSON -> zmx -> JSON stays exact."""
    for digits in range(1, 18):
        cand = float(f"{raw:.{digits}g}")
        if forward(cand) == written:
            return cand
    return raw


def _radius(c: float) -> float:
    return _shortest(1.0 / c, c, _curv)


def _from_um(um: float) -> float:
    return _shortest(um * 1000.0, um, _to_um)


def _to_um(nm: float) -> float:
    return _exact(nm, nm / 1000.0, lambda um: um * 1000.0)


def _curv(radius: float) -> float:
    return _exact(radius, 1.0 / radius, lambda c: 1.0 / c)
