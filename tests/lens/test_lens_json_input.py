"""Hostile JSON lens files: one PrescriptionError naming the file (and
the line where there is one), never a traceback; crossing surfaces are named even when the
lens gives no semi-diameters."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from optix_e2e.cli import main
from optix_e2e.lens import Lens
from optix_e2e.lens.prescription import PrescriptionError


def _cooke() -> dict:
    return Lens.load("cooke-f50").raw


def _write(tmp_path, text: "str | bytes", name="lens.json"):
    p = tmp_path / name
    (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
    return p


def _huge_number(tmp_path):
    t = json.dumps(_cooke())
    i = t.index('"thickness": ') + len('"thickness": ')
    return _write(tmp_path, t[:i] + "1" + "0" * 400 + t[t.index(",", i) :])


def _catalog_number(tmp_path):
    d = _cooke()
    d["surfaces"][0]["material"] = {"glass": "SK16", "catalog": 3}
    return _write(tmp_path, json.dumps(d))


def _glass_number(tmp_path):
    d = _cooke()
    d["surfaces"][0]["material"] = {"glass": 7}
    return _write(tmp_path, json.dumps(d))


def _latin1(tmp_path):
    t = json.dumps(_cooke(), indent=1).replace('"name": "', '"name": "\xe9', 1)
    return _write(tmp_path, t.encode("latin-1"))


def _deep_array(tmp_path):
    return _write(tmp_path, '{"name": ' + "[" * 100000 + "]" * 100000 + "}")


def _deep_description(tmp_path):
    d = _cooke()
    d["description"] = 0
    return _write(tmp_path, json.dumps(d).replace('"description": 0', '"description": ' + "[" * 3000 + "]" * 3000))


@pytest.mark.parametrize(
    "make, needle",
    [
        (_huge_number, "thickness: must be finite, got a 401-digit number"),
        (_catalog_number, "material.catalog: must be a catalog name"),
        (_glass_number, "material.glass: must be a glass name"),
        (_latin1, ":2:11:"),  # line and column of the bad byte
        (_deep_array, "nested too deeply"),
        (_deep_description, "nested too deeply"),
    ],
)
def test_bad_json_lens_is_one_error_naming_the_file(tmp_path, make, needle):
    path = make(tmp_path)
    with pytest.raises(PrescriptionError) as err:
        Lens.load(str(path))
    msg = str(err.value)
    assert msg.startswith(str(path)) and needle in msg, msg
    res = CliRunner().invoke(main, ["lens", "info", str(path)])
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ") and str(path) in lines[0], res.output


def test_zero_thickness_glass_without_semi_diameters_names_the_crossing_surfaces(tmp_path):
    d = _cooke()
    assert all(s.get("semi_diameter") is None for s in d["surfaces"])
    d["surfaces"][0]["thickness"] = 0.0  # the first crown, biconvex, at zero centre thickness
    path = _write(tmp_path, json.dumps(d))
    with pytest.raises(PrescriptionError, match=r"surfaces 1 and 2 cross at height"):
        Lens.load(str(path))
    res = CliRunner().invoke(main, ["lens", "info", str(path)])
    assert res.exit_code == 1 and "surfaces 1 and 2 cross" in res.output and "no ray" not in res.output


def test_beam_check_passes_the_bundled_lenses_and_a_thin_real_gap():
    for name in ("cooke-f50", "paper-triplet", "double-gauss-f5"):
        Lens.load(name)
    d = _cooke()
    d["surfaces"][1]["thickness"] = 2.0  # air gap 2-3 a third of nominal: the surfaces still part
    Lens(d)
