"""A finite object distance and odd aspheric terms, as real Zemax files use them: the
object point of an angle field where OpticStudio puts it (its own semi-diameter of the
object surface), object-space NA, object-height fields, PSFs, round trips, and axicons."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import WHERE_SHARED, shared_dir

from optix_e2e.lens import Lens
from optix_e2e.lens.prescription import PrescriptionError
from optix_e2e.lens.zemax import ZemaxError

REPO_ROOT = Path(__file__).resolve().parents[2]
SAMPLES = shared_dir("zmx-samples", "OPTIX_ZMX_SAMPLES_DIR")
BROKEN = REPO_ROOT / "tests" / "data" / "zmx" / "broken"


def sample(name: str) -> Path:
    path = SAMPLES / name
    if not path.is_file():
        pytest.fail(f"missing {path}: {WHERE_SHARED}", pytrace=False)
    return path


def test_matched_pair_object_point_is_opticstudios():
    """Thorlabs' 1:1 matched achromat pair: object 15.7 mm away, fields 0 and 4 deg. The
    file records OpticStudio's semi-diameter of the object surface (MEMA 1.5121250354 mm),
    which is the height of the 4 deg object point: ours is L tan(4 deg), L = object to
    paraxial entrance pupil."""
    lens = Lens.from_file(sample("zmf_THORLABS/MAP051919-A.zmx"), strict=False)
    assert lens.object_distance == pytest.approx(15.70937859976, abs=1e-9)
    par = lens.paraxial()
    h = par["object_to_pupil_mm"] * math.tan(math.radians(4.0))
    assert h == pytest.approx(1.5121250354321296, rel=1e-9)
    # the chief ray leaves that object point: back along it to the object plane
    t = lens.trace_field(4.0, np.array([0.0]), np.array([0.0]))
    o, d = t["origin"][0], t["launch_direction"][0]
    at_object = o + (-lens.object_distance - o[2]) / d[2] * d
    assert at_object[1] == pytest.approx(-h, abs=1e-9) and at_object[0] == 0.0
    # 1:1 imaging: the paraxial image of the object point is as high as the object, inverted
    assert par["paraxial_image_height_mm"] == pytest.approx(h, rel=0.02)
    assert abs(par["back_focus_shift_mm"]) < 1.0


def test_object_space_na_fiber_collimator():
    """OBNA 0.14 with the fiber tip on the object surface (DISZ 0, then 8.11 mm of air): the
    marginal ray leaves the fiber at sin(u) = 0.14; EFL as the part's name states."""
    lens = Lens.from_file(sample("zmf_THORLABS/F220APC-1550.zmx"), strict=False)
    assert lens.data["aperture"] == {"type": "object_na", "value": pytest.approx(0.14)}
    assert lens.object_distance == 0.0
    t = lens.trace_field(0.0, np.array([0.0, 0.0]), np.array([1.0, -1.0]))
    assert t["launch_direction"][:, 1] == pytest.approx([0.14, -0.14], abs=1e-12)
    assert (t["status"] == 0).all()
    assert lens.paraxial()["efl_mm"] == pytest.approx(11.32, rel=1e-3)


def test_finite_object_psfs_agree_between_methods():
    lens = Lens.from_file(sample("zmf_THORLABS/MAP051919-A.zmx"), strict=False)
    a, _ = lens.psf(0.0, method="fft", pixel_um=0.5, size=64, pupil_samples=64)
    b, _ = lens.psf(0.0, method="huygens", pixel_um=0.5, size=64, pupil_samples=64)
    assert np.isfinite(a).all() and a.sum() == pytest.approx(b.sum(), rel=0.01)
    assert np.abs(a - b).sum() / b.sum() < 0.01
    info = lens.spot(4.0)
    assert info["relative_illumination"] is not None and 0 < info["relative_illumination"] <= 1.05


def test_object_height_fields_become_the_same_object_points(tmp_path):
    """FTYP 1 (object heights) of a finite object: imported as the angles whose object points
    are those heights, noted in the import report."""
    text = (BROKEN / "finite_object.zmx").read_text()
    text = text.replace("FTYP 0 0 3", "FTYP 1 0 3", 1)
    assert "FTYP 1 0 3" in text
    path = tmp_path / "heights.zmx"
    path.write_text(text)
    ys = [float(v) for v in next(ln for ln in text.splitlines() if ln.startswith("YFLN")).split()[1:4]]
    lens = Lens.from_file(path)
    L = lens.paraxial()["object_to_pupil_mm"]
    assert lens.fields_deg == pytest.approx([math.degrees(math.atan(y / L)) for y in ys], rel=1e-12)
    assert any("object-height fields" in n for n in lens.zemax_import.notes)
    # with a pupil that floats by the stop's size, placed before the fields: the same angles
    path.write_text(text.replace("ENPD 1.0E+1", "FLOA", 1))
    floating = Lens.from_file(path)
    assert floating.data["aperture"]["type"] == "epd"
    assert floating.fields_deg == pytest.approx(lens.fields_deg, rel=1e-12)
    # an object-height field with the object at infinity stays an error
    with pytest.raises(ZemaxError, match="object height"):
        Lens.load(BROKEN / "height_fields.zmx")


def test_finite_object_and_odd_terms_round_trip(tmp_path):
    for name in ("zmf_THORLABS/F220APC-1550.zmx", "zmf_THORLABS/AX2520-A.zmx", "zmf_THORLABS/MAP051919-A.zmx"):
        lens = Lens.from_file(sample(name), strict=False)
        back = Lens.from_file(lens.save(tmp_path / "out.zmx"))
        assert back.object_distance == lens.object_distance
        assert back.data["aperture"] == lens.data["aperture"]
        for s, t in zip(lens.surfaces, back.surfaces):
            assert (s.get("aspheric") or {}) == pytest.approx(t.get("aspheric") or {}, rel=1e-12)
        assert back.paraxial()["efl_mm"] == pytest.approx(lens.paraxial()["efl_mm"], rel=1e-12)


def test_axicon_imports_with_its_cone():
    """Thorlabs AX2520-A, a 20 deg UVFS axicon: ODDASPHE with an r^1 term only; no paraxial
    power (EFL infinite), and parallel rays leave at the cone's Snell angle."""
    lens = Lens.from_file(sample("zmf_THORLABS/AX2520-A.zmx"), strict=False)
    cone = next(s for s in lens.surfaces if "a1" in (s.get("aspheric") or {}))
    alpha = math.atan(abs(cone["aspheric"]["a1"]))
    assert math.degrees(alpha) == pytest.approx(20.0, abs=0.05)
    assert math.isinf(lens.paraxial()["efl_mm"])
    n = float(lens.refractive_indices()[1])
    t = lens.trace_field(0.0, np.array([0.0]), np.array([0.5]))
    d = t["direction"][0]
    assert abs(math.atan2(abs(d[1]), d[2])) == pytest.approx(math.asin(n * math.sin(alpha)) - alpha, abs=1e-9)


def test_bad_object_input_is_one_clear_error():
    base = Lens.load("cooke-f50").data
    for patch, msg in [
        ({"object_distance": -3}, "object_distance: must be >= 0"),
        ({"object_distance": "far"}, "object_distance: must be a number"),
        ({"aperture": {"type": "object_na", "value": 0.1}}, 'needs a finite "object_distance"'),
        ({"aperture": {"type": "object_na", "value": 1.2}, "object_distance": 10}, "below 1"),
        ({"surfaces": [dict(base["surfaces"][0], aspheric={"a9": 1e-9})] + base["surfaces"][1:]}, "unknown key"),
    ]:
        with pytest.raises(PrescriptionError, match=msg):
            Lens(dict(base, **patch))
    text = (BROKEN / "finite_object.zmx").read_text().replace("DISZ 1.0E+3", "DISZ -5", 1)
    with pytest.raises(ZemaxError, match="virtual object"):
        from optix_e2e.lens.zemax import parse_zmx

        parse_zmx(text, "t.zmx")
