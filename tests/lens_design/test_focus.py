"""Refocusing (optix_e2e.lens_design.focus): the closed-form best focus against a brute-force scan of
the engine's own RMS spot, and the paraxial focus against the paraxial BFL."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from optix_e2e import _engine
from optix_e2e.lens import Lens
from optix_e2e.lens_design.focus import best_focus_shift, refocus


def _mean_ms(lens: dict, fields, wls, dz: float) -> float:
    d = copy.deepcopy(lens)
    d["surfaces"][-1]["thickness"] += dz
    js = json.dumps(d)
    return float(np.mean([_engine.spot(js, f, wls, None, 48)["rms_um"] ** 2 for f in fields]))


@pytest.mark.parametrize("name, defocus", [("paper-triplet", 0.0), ("paper-triplet", 0.6), ("cooke-f50", -1.5)])
def test_best_focus_is_the_minimum_of_the_engine_spot(name, defocus):
    lens = copy.deepcopy(Lens.load(name).data)
    for s in lens["surfaces"]:
        s["semi_diameter"] = None
    lens["surfaces"][-1]["thickness"] += defocus
    fields, wls = Lens.load(name).fields_deg, Lens.load(name).wavelengths_nm
    dz = best_focus_shift(json.dumps(lens), fields, wls)
    # a scan of the engine's hexapolar spot (an independent pupil sampling) around it
    scan = np.linspace(dz - 0.05, dz + 0.05, 11)
    ms = [_mean_ms(lens, fields, wls, z) for z in scan]
    assert abs(scan[int(np.argmin(ms))] - dz) <= 0.01 + 1e-12
    assert _mean_ms(lens, fields, wls, dz) <= _mean_ms(lens, fields, wls, 0.0) + 1e-9
    if defocus:
        assert dz == pytest.approx(-defocus, abs=0.15)  # undoes most of the added defocus


def test_refocus_modes():
    base = Lens.load("paper-triplet")
    d = copy.deepcopy(base.data)
    refocus(d, "paraxial", base.fields_deg, base.wavelengths_nm, primary_nm=550.0)
    assert d["surfaces"][-1]["thickness"] == pytest.approx(base.paraxial()["bfl_mm"], rel=1e-12)
    d2 = copy.deepcopy(base.data)
    assert refocus(d2, "fixed", base.fields_deg, base.wavelengths_nm) == base.data
    with pytest.raises(ValueError, match="focus must be"):
        refocus(d2, "auto", base.fields_deg, base.wavelengths_nm)
