"""The lens as sampled designs are traced: the aperture follows the f-number or EPD setting
(the stop's clear semi-diameter is dropped), and ``"auto"`` drops every clear aperture."""

from __future__ import annotations

import copy

from .model import Lens


def engine_base(base: "Lens | dict", apertures: str) -> dict:
    """The base prescription (a Lens or a resolved lens dict) the sampled designs are traced
    with.  The aperture is always the lens's f-number / EPD (the stop's clear semi-diameter is
    dropped: the iris follows the aperture setting as the design changes); ``"auto"`` drops
    every clear aperture."""
    d = copy.deepcopy(base.data if isinstance(base, Lens) else base)
    for s in d["surfaces"]:
        if apertures == "auto" or s.get("stop"):
            s["semi_diameter"] = None
    return d
