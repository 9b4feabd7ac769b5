"""Indices of the Cooke triplet's glasses against the reference file's "n" values."""

import numpy as np
import pytest

from optix_e2e.lens import glass

WAVELENGTHS_UM = ("0.4800", "0.5500", "0.6500")


def _reference_glasses(ref_prescription):
    for s in ref_prescription["surfaces"]:
        m = s["material_after"]
        if m["name"] != "air":
            yield s["index"], m


def test_resolved_formula_matches_reference_definition(ref_prescription):
    for _, m in _reference_glasses(ref_prescription):
        g = glass.resolve(m["name"], m["catalog"])
        assert f"formula {g.formula}" == m["formula"]
        assert list(g.coefficients) == m["coefficients"]
        assert list(g.range_um) == m["valid_range_um"]


def test_numpy_indices_match_reference(ref_prescription):
    """Independent evaluation of the resolved formulas (numpy, not the engine)."""
    for _, m in _reference_glasses(ref_prescription):
        g = glass.resolve(m["name"], m["catalog"])
        for wl in WAVELENGTHS_UM:
            assert abs(float(g.n(float(wl))) - m["n"][wl]) < 1e-9, (m["name"], wl)


@pytest.mark.parametrize("wl", WAVELENGTHS_UM)
def test_engine_indices_match_reference(cooke, ref_prescription, wl):
    n = np.asarray(cooke.refractive_indices(float(wl) * 1000.0))
    assert n.shape == (len(cooke.surfaces) + 1,)
    assert n[0] == 1.0  # object space is air
    for s in ref_prescription["surfaces"][1:-1]:
        assert abs(n[s["index"]] - s["material_after"]["n"][wl]) < 1e-9, (s["index"], wl)
