"""Lens loading, validation errors and material resolution (no engine needed)."""

import json
import math

import pytest

from optix_e2e.lens import Lens, LensLoadError, bundled_lenses
from optix_e2e.lens.prescription import PrescriptionError


def singlet(**surface0):
    s0 = {"radius": 50.0, "thickness": 5.0, "material": {"n": 1.5}, "stop": True}
    s0.update(surface0)
    return {
        "name": "singlet",
        "aperture": {"type": "epd", "value": 10.0},
        "fields_deg": [0.0, 5.0],
        "wavelengths_nm": [486.1, 587.6, 656.3],
        "surfaces": [s0, {"radius": "inf", "thickness": 95.0, "material": "air"}],
    }


def write(tmp_path, data, name="lens.json"):
    p = tmp_path / name
    p.write_text(data if isinstance(data, str) else json.dumps(data, indent=1))
    return p


def test_bundled_cooke_loads_and_resolves():
    assert "cooke-f50" in bundled_lenses()
    lens = Lens.load("cooke-f50")
    data = json.loads(lens.to_engine_json())
    mats = [s["material"] for s in data["surfaces"]]
    assert mats[1] == "air" and mats[0]["formula"] == 3 and mats[2]["formula"] == 2
    assert "glass" not in json.dumps(mats)
    assert lens.primary_wavelength_nm == 550.0 and lens.max_field_deg == 20.0


def test_bundled_cooke_matches_reference_prescription(ref_prescription):
    lens = Lens.load("cooke-f50")
    ref = [s for s in ref_prescription["surfaces"] if s["role"] == "refracting"]
    assert len(lens.surfaces) == len(ref)
    for s, r in zip(lens.surfaces, ref):
        assert s["radius"] == r["radius_mm"] and s["thickness"] == r["thickness_after_mm"]
        assert s.get("stop", False) == r["is_stop"]
        assert s.get("semi_diameter") is None
    assert [i for i, s in enumerate(lens.surfaces, 1) if s.get("stop")] == [ref_prescription["stop_surface_index"]]
    assert lens.data["aperture"] == {"type": "epd", "value": ref_prescription["aperture"]["value"]}
    assert lens.fields_deg == ref_prescription["fields"]["values_deg"]
    assert [w / 1000 for w in lens.wavelengths_nm] == ref_prescription["wavelengths_um"]


def test_load_from_path_dict_and_lens(tmp_path):
    p = write(tmp_path, singlet())
    a, b = Lens.load(p), Lens.load(str(p))
    assert a.to_engine_json() == b.to_engine_json() == Lens.load(singlet()).to_engine_json()
    assert Lens.load(a) is a
    assert a.primary_wavelength_nm == 587.6  # middle listed wavelength
    assert a.wavelength_weights == [1.0, 1.0, 1.0]


def test_catalog_names_resolve_in_surfaces():
    lens = Lens(singlet(material="n-sf11"))
    m = lens.surfaces[0]["material"]
    assert m["name"] == "N-SF11 (schott)" and m["formula"] == 2
    lens = Lens(singlet(material={"glass": "PMMA"}))
    assert lens.surfaces[0]["material"]["name"] == "PMMA (organic)"


def test_missing_file():
    with pytest.raises(LensLoadError, match="nope.json: no such lens file"):
        Lens.load("nope.json")
    with pytest.raises(LensLoadError, match="neither a lens file nor a bundled lens.*cooke-f50"):
        Lens.load("nope")


def test_bad_json_names_file_and_line(tmp_path):
    text = json.dumps(singlet(), indent=1).splitlines()
    text[3] = text[3] + " oops"
    p = write(tmp_path, "\n".join(text), "broken.json")
    with pytest.raises(LensLoadError) as err:
        Lens.load(p)
    assert str(err.value).startswith(f"{p}:4:") and "invalid JSON" in str(err.value)


def test_missing_thickness_names_file_and_surface(tmp_path):
    data = singlet()
    del data["surfaces"][1]["thickness"]
    p = write(tmp_path, data, "nothick.json")
    with pytest.raises(PrescriptionError, match=r"nothick\.json: surface 2 \(surfaces\[1\]\) thickness: missing"):
        Lens.load(p)


def test_unknown_glass_names_surface_and_close_matches(tmp_path):
    p = write(tmp_path, singlet(material="N-SF111"))
    with pytest.raises(PrescriptionError) as err:
        Lens.load(p)
    msg = str(err.value)
    assert (
        msg.startswith(f"{p}: surface 1 (surfaces[0]) material: unknown glass 'N-SF111'") and "N-SF11 (schott)" in msg
    )


@pytest.mark.parametrize(
    "change, pattern",
    [
        ({"thickness": math.nan}, r"surface 1 \(surfaces\[0\]\) thickness: must be finite"),
        ({"thickness": "5"}, r"surface 1 \(surfaces\[0\]\) thickness: must be a number"),
        ({"radius": 0}, r"surface 1 \(surfaces\[0\]\) radius: must not be 0"),
        ({"radius": "flat"}, r"surface 1 \(surfaces\[0\]\) radius: must be a number"),
        ({"curvature": 0.02}, r"surface 1 \(surfaces\[0\]\): give \"radius\" or \"curvature\", not both"),
        ({"thicknes": 1.0}, r"surface 1 \(surfaces\[0\]\): unknown key\(s\) 'thicknes'"),
        ({"stop": False}, r"exactly one surface must have \"stop\": true, found 0"),
        ({"semi_diameter": -1.0}, r"surface 1 \(surfaces\[0\]\) semi_diameter: must be > 0"),
        (
            {"aspheric": {"a9": 1e-5}},
            r"surface 1 \(surfaces\[0\]\) aspheric: unknown key\(s\) 'a9'",
        ),  # odd terms stop at a7
        (
            {"material": {"formula": 12, "coefficients": [1], "range_um": [0.4, 0.7]}},
            r"formula: must be an integer 1-9",
        ),
        ({"material": {"nd": 1.5}}, r"material\.vd: must be a number"),
        ({"material": 42}, r"surface 1 \(surfaces\[0\]\) material: must be \"air\""),
    ],
)
def test_surface_validation_errors(change, pattern):
    with pytest.raises(PrescriptionError, match=pattern):
        Lens(singlet(**change))


@pytest.mark.parametrize(
    "change, pattern",
    [
        ({"aperture": {"type": "na", "value": 0.1}}, r"aperture\.type"),
        ({"aperture": {"type": "epd", "value": -1}}, r"aperture\.value: must be > 0"),
        ({"fields_deg": []}, r"fields_deg: must be a non-empty list"),
        ({"fields_deg": [0, 95]}, r"fields_deg\[1\]: must be < 90"),
        ({"wavelengths_nm": [550, -1]}, r"wavelengths_nm\[1\]: must be > 0"),
        ({"wavelength_weights": [1, 1]}, r"wavelength_weights: has 2 entries for 3"),
        ({"units": "inch"}, r"units"),
        ({"focal": 50}, r"top level: unknown key\(s\) 'focal'"),
    ],
)
def test_top_level_validation_errors(change, pattern):
    data = singlet()
    data.update(change)
    with pytest.raises(PrescriptionError, match=pattern):
        Lens(data, source="x.json")


def test_two_stops_rejected():
    data = singlet()
    data["surfaces"][1]["stop"] = True
    with pytest.raises(PrescriptionError, match=r"found 2 \(surfaces 1, 2\)"):
        Lens(data)


def test_material_forms_pass_through():
    for m in (
        {"n": 1.6},
        {"nd": 1.5168, "vd": 64.17},
        {"tabulated": [[0.4, 1.53], [0.7, 1.51]], "name": "t"},
        {
            "formula": 1,
            "coefficients": [0, 1.03961212, 0.07746, 0.23179, 0.1414, 1.01046945, 10.3317],
            "range_um": [0.3, 2.5],
            "name": "bk7ish",
        },
    ):
        assert Lens(singlet(material=m)).surfaces[0]["material"] == m


def test_input_dict_not_mutated():
    data = singlet(material="N-SF11", radius="Infinity")
    before = json.dumps(data)
    Lens(data)
    assert json.dumps(data) == before
