"""Zemax .zmx import/export (docs/zemax.md): hand-made files in tests/data/zmx, round
trips through our reader and writer, and cross-checks against optiland 0.6.3's own
.zmx reader and writer (an independent implementation from PyPI)."""

import json
import math
import warnings
from pathlib import Path

import pytest
from click.testing import CliRunner

from optix_e2e.cli import main
from optix_e2e.lens import Lens
from optix_e2e.lens.zemax import ZemaxError, parse_zmx, read_zmx, zmx_text

DATA = Path(__file__).parents[1] / "data" / "zmx"
BROKEN = DATA / "broken"


def cooke_as_the_files_name_it() -> Lens:
    """The bundled Cooke triplet with the SK16 the hand-made files resolve: their GCAT is
    SCHOTT HIKARI, and Schott's own SK16 (obsolete, from its AGF catalog) is nearer the nd
    and vd their GLAS lines record than Hikari's, which the bundled lens names."""
    from optix_e2e.lens import BUNDLED_DIR

    data = json.loads((BUNDLED_DIR / "cooke-f50.json").read_text())
    for s in data["surfaces"]:
        if s["material"] == {"glass": "SK16", "catalog": "hikari"}:
            s["material"] = {"glass": "SK16", "catalog": "schott"}
    return Lens(data)


# A lens using every supported field: even aspheres up to a16, conics, model glass
# (dispersive and constant), plastics by their Zemax names, clear apertures, names,
# an f-number aperture, non-uniform weights and a primary wavelength that is not the middle.
FULL = {
    "name": "full-featured",
    "aperture": {"type": "fno", "value": 4.0},
    "fields_deg": [0.0, 7.5, 15.0],
    "wavelengths_nm": [486.1327, 587.5618, 656.2725],
    "wavelength_weights": [1.0, 2.0, 0.5],
    "primary_wavelength_nm": 656.2725,
    "surfaces": [
        {
            "radius": 20.0,
            "thickness": 4.0,
            "material": {"nd": 1.5168, "vd": 64.17},
            "conic": -0.5,
            "aspheric": {"a4": -2.5e-5, "a6": 1.25e-7, "a8": -3e-10},
            "semi_diameter": 6.0,
            "name": "front asphere",
        },
        {"radius": -60.0, "thickness": 2.0, "material": "air", "semi_diameter": 6.0},
        {"radius": "inf", "thickness": 2.0, "material": "air", "stop": True, "semi_diameter": 3.5},
        {"radius": -25.0, "thickness": 2.0, "material": "POLYCARB", "semi_diameter": 5.0},
        {
            "radius": -40.0,
            "thickness": 1.0,
            "material": "air",
            "aspheric": {"a4": 1e-6, "a10": 2e-13, "a16": 1e-20},
            "semi_diameter": 6.0,
        },
        {"radius": 300.0, "thickness": 2.0, "material": "PMMA", "conic": 3.0, "semi_diameter": 6.0},
        {"radius": -300.0, "thickness": 1.5, "material": {"n": 1.6}, "semi_diameter": 6.0},
        {"radius": 1e3 / 3, "thickness": 25.0, "material": "air", "semi_diameter": 6.0},
    ],
    "image": {"semi_diameter": 9.0},
}


def _roundtrip(lens: Lens, tmp_path, name="rt.zmx", **kw) -> Lens:
    path = lens.save(tmp_path / name, **kw)
    return Lens.load(path)


def _same_optics(a: Lens, b: Lens):
    """Every supported field equal, materials compared resolved (catalog page identity). A
    surface of ``a`` without a semi-diameter comes back with the automatic one the writer
    puts in its DIAM line (the beam's footprint, which our reader keeps as a clear aperture
    that clips none of those rays: docs/zemax.md)."""
    for key in ("aperture", "fields_deg", "wavelengths_nm", "primary_wavelength_nm", "image"):
        assert a.data.get(key) == b.data.get(key), key
    auto = a.zmx_footprint() if any(s.get("semi_diameter") is None for s in a.data["surfaces"]) else None
    assert len(a.data["surfaces"]) == len(b.data["surfaces"])
    for i, (sa, sb) in enumerate(zip(a.data["surfaces"], b.data["surfaces"])):
        if sa.get("semi_diameter") is None and sb.get("semi_diameter") is not None:
            assert sb["semi_diameter"] == pytest.approx(auto[i], rel=1e-12), i
            sb = {k: v for k, v in sb.items() if k != "semi_diameter"}
        assert sa == sb, f"surface {i + 1}"
    assert a.wavelength_weights == b.wavelength_weights
    assert a.name == b.name


# ----------------------------------------------------------------------------- round trips
def test_bundled_cooke_json_zmx_json_exact(tmp_path):
    cooke = Lens.load("cooke-f50")
    back = _roundtrip(cooke, tmp_path)
    _same_optics(cooke, back)  # bit-exact radii, thicknesses, glass pages
    assert back.raw["surfaces"][2]["material"] == {"glass": "F2", "catalog": "schott"}
    assert back.raw["surfaces"][0]["material"] == {"glass": "SK16", "catalog": "hikari"}
    assert back.paraxial() == cooke.paraxial()


def test_full_featured_json_zmx_json_exact(tmp_path):
    lens = Lens(FULL)
    back = _roundtrip(lens, tmp_path)
    _same_optics(lens, back)
    raw = back.raw["surfaces"]
    assert raw[0]["aspheric"] == FULL["surfaces"][0]["aspheric"] and raw[0]["conic"] == -0.5
    assert raw[0]["material"] == {"nd": 1.5168, "vd": 64.17} and raw[0]["name"] == "front asphere"
    assert raw[4]["aspheric"] == FULL["surfaces"][4]["aspheric"]
    assert raw[6]["material"] == {"n": 1.6}
    assert raw[3]["material"] == {"glass": "polycarbonate", "catalog": "organic"}
    assert raw[2]["stop"] is True and raw[2]["radius"] == "inf"
    assert raw[7]["radius"] == FULL["surfaces"][7]["radius"]  # 1/(1/R) made exact by the writer
    assert back.raw["image"] == {"semi_diameter": 9.0}
    assert back.raw["aperture"] == {"type": "fno", "value": 4.0}
    assert back.primary_wavelength_nm == 656.2725


def test_radius_and_wavelength_conversions_are_exact():
    """1/(1/R) != R for some doubles (-28.37731 is one); writer and reader together give
    back every radius and wavelength exactly (20000 random values of 1-8 decimals)."""
    import random

    from optix_e2e.lens.zemax import _curv, _from_um, _radius, _to_um

    assert 1.0 / (1.0 / -28.37731) != -28.37731 and _radius(_curv(-28.37731)) == -28.37731
    rng = random.Random(1)
    for _ in range(20000):
        r = round(rng.uniform(-500, 500), rng.randint(1, 8)) or 1.0
        w = round(rng.uniform(300, 1100), rng.randint(0, 7))
        assert _radius(_curv(r)) == r and _from_um(_to_um(w)) == w, (r, w)


def test_zmx_lens_zmx_lens_equal(tmp_path):
    for name in ("cooke_utf8.zmx", "asphere_plastic.zmx", "cooke_floa.zmx"):
        first = Lens.load(DATA / name)
        second = _roundtrip(first, tmp_path, name)
        _same_optics(first, second)
        assert second.to_zmx() == first.to_zmx()


def test_utf16_output_and_input(tmp_path):
    lens = Lens(FULL)
    path = lens.save(tmp_path / "u16.zmx", encoding="utf-16")
    assert path.read_bytes()[:2] == b"\xff\xfe"
    imp = read_zmx(path)
    assert imp.notes[0] == "encoding utf-16"
    _same_optics(lens, Lens(imp.data))


def test_handmade_utf8_and_utf16_files_agree():
    a, b = Lens.load(DATA / "cooke_utf8.zmx"), Lens.load(DATA / "cooke_utf16.zmx")
    _same_optics(a, b)
    assert a.zemax_import.notes[0] == "encoding utf-8" and b.zemax_import.notes[0] == "encoding utf-16"


def test_handmade_cooke_matches_bundled():
    """OpticStudio layout: 24 WAVM slots, 12 field slots, solve columns, automatic DIAMs."""
    zmx, ref = Lens.load(DATA / "cooke_utf8.zmx"), cooke_as_the_files_name_it()
    assert zmx.name == "Cooke triplet f/5 (hand-made, OpticStudio layout)"
    assert zmx.fields_deg == [0.0, 14.0, 20.0] and zmx.wavelengths_nm == [480.0, 550.0, 650.0]
    assert zmx.primary_wavelength_nm == 550.0
    assert [s["semi_diameter"] for s in zmx.surfaces] == [9.33, 8.89, 4.41, 3.86, 6.98, 7.34]
    assert zmx.surfaces[0]["name"] == "front crown"
    for key in ("efl_mm", "bfl_mm", "epd_mm"):
        assert zmx.paraxial()[key] == pytest.approx(ref.paraxial()[key], rel=1e-12)
    # the DIAMs are the beam footprints (plus margin): no ray is clipped. The relative
    # illumination agrees to its pupil grid's accuracy (the rim check may pick the fine grid
    # where a DIAM grazes the pupil's edge: 4 rings against 24 differ by ~3e-5)
    for f in zmx.fields_deg:
        assert zmx.spot(f, rings=16)["vignetting"] == ref.spot(f, rings=16)["vignetting"] == 1.0
        assert zmx.spot(f, rings=16)["relative_illumination"] == pytest.approx(
            ref.spot(f, rings=16)["relative_illumination"], rel=1e-4
        )
    ignored = {k for _, k, _ in zmx.zemax_import.ignored}
    assert {"HIDE", "MIRR", "SLAB", "POPS", "RAIM", "FWGN", "WAVM"} <= ignored
    assert "inactive wavelength slot (FTYP declares 3)" in zmx.zemax_import.ignored_summary()


def test_bundled_lenses_roundtrip_exactly(tmp_path):
    from optix_e2e.lens import bundled_lenses

    for name in bundled_lenses():
        lens = Lens.load(name)
        _same_optics(lens, _roundtrip(lens, tmp_path, f"{name}.zmx"))


def test_vendor_glass_names_in_zmx(tmp_path):
    """Zemax-style names from several vendors' catalogs, found through GCAT."""
    names = ["S-BSL7", "H-K9L", "E-FD1", "PMMA", "POLYCARB", "N-BK7", "S-LAH66"]
    surfs = "".join(
        f"SURF {i}\n  CURV 0\n  DISZ 1\n  GLAS {g} 0 0 0 0\nSURF {i + 1}\n  CURV 0\n  DISZ 1\n"
        for i, g in zip(range(1, 2 * len(names), 2), names)
    )
    text = (
        "MODE SEQ\nENPD 5\nGCAT OHARA CDGM HOYA MISC SCHOTT\nFTYP 0 0 1 1 0 0 0\nYFLN 0\n"
        "WAVM 1 0.55 1\nSURF 0\n  DISZ INFINITY\n"
        + surfs.replace("SURF 1\n", "SURF 1\n  STOP\n", 1)
        + f"SURF {2 * len(names) + 1}\n  DISZ 0\n"
    )
    imp = parse_zmx(text, source="<t>")
    got = [s["material"] for s in imp.data["surfaces"] if s["material"] != "air"]
    assert got == [
        {"glass": "S-BSL7", "catalog": "ohara"},
        {"glass": "H-K9L", "catalog": "cdgm"},
        {"glass": "E-FD1", "catalog": "hoya"},
        {"glass": "PMMA", "catalog": "organic"},
        {"glass": "polycarbonate", "catalog": "organic"},
        {"glass": "N-BK7", "catalog": "schott"},
        {"glass": "S-LAH66", "catalog": "ohara"},
    ]
    # a glass outside the file's catalogs is not substituted: the error says where it is
    with pytest.raises(
        ZemaxError,
        match=r"SURF 1: unknown glass 'S-BSL7' in the file's catalogs "
        r"\(GCAT SCHOTT MISC\); not substituted: S-BSL7 exists in catalog ohara",
    ):
        parse_zmx(text.replace("GCAT OHARA CDGM HOYA MISC SCHOTT", "GCAT SCHOTT MISC"), source="<t>")
    lens = Lens(imp.data)
    _same_optics(lens, _roundtrip(lens, tmp_path))


def test_legacy_wavl_layout():
    lens = Lens.load(DATA / "cooke_legacy_wavl.zmx")
    assert lens.wavelengths_nm == [480.0, 550.0, 650.0] and lens.wavelength_weights == [1.0, 2.0, 1.0]
    assert lens.fields_deg == [0.0, 14.0, 20.0]
    assert lens.paraxial()["efl_mm"] == pytest.approx(cooke_as_the_files_name_it().paraxial()["efl_mm"], rel=1e-12)


def test_lens_units_cm_converted():
    """Lengths scale by 10, a_2i by 10^(1-2i): the same lens as the mm file."""
    mm, cm = Lens.load(DATA / "asphere_plastic.zmx"), Lens.load(DATA / "asphere_plastic_cm.zmx")
    for s_mm, s_cm in zip(mm.surfaces, cm.surfaces):
        for key in ("radius", "thickness", "semi_diameter", "conic"):
            if isinstance(s_mm.get(key), float):
                assert s_cm[key] == pytest.approx(s_mm[key], rel=1e-14), key
        for k, v in s_mm.get("aspheric", {}).items():
            assert s_cm["aspheric"][k] == pytest.approx(v, rel=1e-14), k
    assert cm.paraxial()["efl_mm"] == pytest.approx(mm.paraxial()["efl_mm"], rel=1e-12)
    assert "lens units CM" in cm.data["description"]


def test_floa_fills_the_stop():
    """FLOA: the EPD makes the paraxial marginal ray fill the stop's DIAM (3.5 mm)."""
    lens = Lens.load(DATA / "cooke_floa.zmx")
    par = lens.paraxial()
    assert par["stop_semi_diameter_mm"] == pytest.approx(3.5, rel=1e-12)
    assert lens.data["aperture"]["type"] == "epd"
    assert "FLOA (float by stop size)" in lens.data["description"]


def test_writer_rejects_what_zemax_cannot_hold():
    bad = json.loads(json.dumps(FULL))
    bad["surfaces"][4]["aspheric"]["a18"] = 1e-22
    with pytest.raises(ZemaxError, match=r"surface 5 \(surfaces\[4\]\) aspheric: a18: Zemax EVENASPH stops at a16"):
        zmx_text(bad)
    formula = Lens(Lens.load("cooke-f50").data)  # resolved: formula materials
    with pytest.raises(ZemaxError, match="formula or tabulated material has no Zemax equivalent"):
        formula.to_zmx()


# ----------------------------------------------------------------------------- broken files
BROKEN_CASES = {
    "truncated.zmx": r"truncated\.zmx:113: GLAS: SURF 5 is the last surface, taken as the image plane, "
    r"but has glass after it: the file looks truncated",
    "truncated_utf16.zmx": r"truncated_utf16\.zmx: cannot decode as utf-16 .*truncated file\?",
    "unknown_surface_type.zmx": r":107: TYPE: SURF 5: toroidal/cylindrical surface \(TOROIDAL\) is not "
    r"supported; supported: STANDARD, EVENASPH, ODDASPHE",
    "unknown_glass.zmx": r":93: GLAS: SURF 3: unknown glass 'N-SF111' in the file's catalogs \(GCAT SCHOTT "
    r"HIKARI\); close matches: N-SF11 \(schott\)",
    "missing_stop.zmx": r": STOP: no surface is marked STOP",
    "coordinate_break.zmx": r":107: TYPE: SURF 5: coordinate break \(tilt/decenter\) \(COORDBRK\) is not "
    r"supported",
    "decentered_aperture.zmx": r":116: OBDC: SURF 5: decentered aperture is not supported",
    "non_sequential.zmx": r":2: MODE: only sequential files are supported \(MODE SEQ\), got 'NSC'",
    "height_fields.zmx": r":14: FTYP: field type 1 \(object height\); only angle fields",
    "x_fields.zmx": r":18: XFLN: x field angles are not supported",
    "unknown_keyword.zmx": r":83: FROB: unknown keyword; not supported by this reader",
    "mirror.zmx": r":93: GLAS: SURF 3: mirrors are not supported",
    "glass_pickup.zmx": r":93: GLAS: SURF 3: glass solve type 2 \(pickup/offset/substitute\) is not supported",
    "two_apertures.zmx": r":8: FNUM: second aperture definition \(first: ENPD on line 7\)",
    "bad_number.zmx": r":92: DISZ: expected a number, got '0\.99O97'",
}


@pytest.mark.parametrize("name", sorted(BROKEN_CASES))
def test_broken_file_gives_its_own_error(name):
    with pytest.raises(ZemaxError, match=BROKEN_CASES[name]) as err:
        Lens.load(BROKEN / name)
    assert str(BROKEN / name) in str(err.value)
    assert isinstance(err.value, ValueError)


def test_lenient_lists_unknown_keyword():
    lens = Lens.from_file(BROKEN / "unknown_keyword.zmx", strict=False)
    assert (83, "FROB", "unknown keyword (lenient mode)") in lens.zemax_import.ignored
    # known-unsupported features fail even when lenient
    with pytest.raises(ZemaxError, match="COORDBRK"):
        Lens.from_file(BROKEN / "coordinate_break.zmx", strict=False)


def test_small_broken_texts():
    head = "MODE SEQ\nENPD 10\nFTYP 0 0 1 1 0 0 0\nYFLN 0\nWAVM 1 0.55 1\n"
    cases = {
        "SURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  GLAS ___BLANK 1 0 1.5 50 0.01\nSURF 2\nSURF 3\n": r"<t>:10: GLAS: SURF 1: model glass dPgF = 0\.01 is not supported",
        "SURF 0\n  DISZ INFINITY\nSURF 1\n  TYPE STANDARD\n  PARM 2 0.001\n  STOP\nSURF 2\n": r"<t>:10: PARM: SURF 1: PARM 2 = 0\.001 has no meaning on a STANDARD surface",
        "SURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\nSURF 2\n  CURV 0.01\n  CONI -1\n  DISZ 0\n": r"<t>:12: CONI: SURF 2 \(image\): a conic image surface is not supported",
        "SURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\n  CLAP 1 3\nSURF 2\n": r"<t>:10: CLAP: SURF 1: annular aperture",
        "UNIT FT\nSURF 0\n": r"<t>:6: UNIT: unknown lens unit 'FT'",
        "ENVD 25 1 0\nSURF 0\n": r"<t>:6: ENVD: environment 25 C, 1 atm",
        "PWAV 3\nSURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\nSURF 2\n": r"<t>:6: PWAV: primary wavelength 3 outside 1\.\.1",
        "SURF 0\n  DISZ INFINITY\nSURF 2\n": r"<t>:8: SURF: surface 2 out of order",
    }
    for body, msg in cases.items():
        with pytest.raises(ZemaxError, match=msg):
            parse_zmx(head + body, source="<t>")
    with pytest.raises(ZemaxError, match="no aperture definition"):
        parse_zmx(head.replace("ENPD 10\n", "") + "SURF 0\n  DISZ INFINITY\nSURF 1\n  STOP\nSURF 2\n", source="<t>")


# ----------------------------------------------------------------------------- optiland cross-checks
optiland_fileio = pytest.importorskip("optiland.fileio", reason="optiland is in the test extra")


def _optiland_first_order(optic):
    """EFL and BFL from optiland's paraxial trace (F2 is measured from the image plane)."""
    last_t = float(optic.surfaces[-2].thickness)
    return float(optic.paraxial.f2()), last_t + float(optic.paraxial.F2())


def _surface_data(optic):
    rows = []
    for s in list(optic.surfaces)[1:-1]:
        g = s.geometry
        coeffs = [float(c) for c in getattr(g, "coefficients", None) or []]
        rows.append((float(g.radius), float(s.thickness), float(getattr(g, "k", 0.0)), coeffs))
    return rows


def _full_for_optiland() -> dict:
    """FULL, evaluated where both tools' model glasses agree.  Zemax-style model glass
    is (nd, vd) plus a dispersion model of each tool's choosing (ours: two-term Cauchy;
    optiland: Buchdahl), so they agree exactly only at the d line: primary 587.5618 nm.
    optiland turns vd = 0 (non-dispersive) into NaN, so that surface gets vd = 40."""
    d = json.loads(json.dumps(FULL))
    d["primary_wavelength_nm"] = 587.5618
    d["surfaces"][6]["material"] = {"nd": 1.6, "vd": 40.0}
    return d


@pytest.mark.parametrize("which", ["cooke", "full", "apo-gauss-8e", "apo-gauss-8e-mv"])
def test_optiland_reads_our_file(tmp_path, which):
    """optiland's own .zmx reader loads our file to the same system: EFL/BFL to 1e-9
    and surface data (radius, thickness, conic, a2..a16, stop). apo-gauss-8e: the eight-element
    lens (HOYA glasses by name; optiland finds them in its own copy of the catalog), and the same
    scaled to the sensor with the camera's wavelengths (apo-gauss-8e-mv)."""
    lens = {
        "cooke": lambda: Lens.load("cooke-f50"),
        "full": lambda: Lens(_full_for_optiland()),
        "apo-gauss-8e": lambda: Lens.load("apo-gauss-8e"),
        "apo-gauss-8e-mv": lambda: Lens.load("apo-gauss-8e-mv"),
    }[which]()
    path = lens.save(tmp_path / f"{which}.zmx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # optiland's fuzzy-match notice for POLYCARB
        optic = optiland_fileio.load_zemax_file(str(path))
    efl, bfl = _optiland_first_order(optic)
    par = lens.paraxial()
    assert efl == pytest.approx(par["efl_mm"], rel=1e-9)
    assert bfl == pytest.approx(par["bfl_mm"], rel=1e-9)
    for i, (s, (r, t, k, coeffs)) in enumerate(zip(lens.raw["surfaces"], _surface_data(optic))):
        radius = math.inf if s["radius"] == "inf" else s["radius"]
        assert r == pytest.approx(radius, rel=1e-9) and t == pytest.approx(s["thickness"], rel=1e-9), i
        assert k == pytest.approx(s.get("conic", 0.0), abs=1e-12), i
        ours = [s.get("aspheric", {}).get(f"a{2 * j}", 0.0) for j in range(1, 9)]
        assert (coeffs or [0.0] * 8) == pytest.approx(ours, rel=1e-9, abs=0), i
        assert optic.surfaces[i + 1].is_stop == bool(s.get("stop"))


def test_we_read_optilands_file(tmp_path):
    """optiland writes its CookeTriplet sample; same glass pages (refractiveindex.info),
    so first-order data must agree to rounding."""
    from optiland.samples.objectives import CookeTriplet

    optic = CookeTriplet()
    path = tmp_path / "optiland_cooke.zmx"
    optiland_fileio.save_zemax_file(optic, str(path))
    lens = Lens.load(path)
    efl, bfl = _optiland_first_order(optic)
    assert lens.paraxial()["efl_mm"] == pytest.approx(efl, rel=1e-9)
    assert lens.paraxial()["bfl_mm"] == pytest.approx(bfl, rel=1e-9)
    assert lens.paraxial()["epd_mm"] == pytest.approx(_epd(optic), rel=1e-12)
    assert lens.fields_deg == [0.0, 14.0, 20.0] and lens.primary_wavelength_nm == 550.0


def _epd(optic) -> float:
    return (
        float(optic.paraxial.EPD().ravel()[0])
        if hasattr(optic.paraxial.EPD(), "ravel")
        else float(optic.paraxial.EPD())
    )


def test_floa_epd_matches_optiland(tmp_path):
    """optiland resolves 'float_by_stop_size' with its own paraxial trace.  Model glass and
    the d line keep glass data out of it (optiland's SK16 page differs from ours by 5e-7
    in n).  optiland's value is the stop *diameter* while Zemax's DIAM is a semi-diameter:
    optiland 0.6.3's reader passes DIAM unchanged (half our EPD); the check sets 2 x DIAM."""
    text = Lens(_full_for_optiland()).to_zmx().replace("FNUM 4.0 0", "FLOA")
    path = tmp_path / "floa.zmx"
    path.write_text(text)
    ours = Lens.load(path)
    assert ours.data["aperture"]["type"] == "epd"
    assert ours.paraxial()["stop_semi_diameter_mm"] == pytest.approx(3.5, rel=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        optic = optiland_fileio.load_zemax_file(str(path))
    assert _epd(optic) == pytest.approx(ours.paraxial()["epd_mm"] / 2, rel=1e-9)
    optic.set_aperture(aperture_type="float_by_stop_size", value=7.0)
    assert ours.paraxial()["epd_mm"] == pytest.approx(_epd(optic), rel=1e-9)


# ----------------------------------------------------------------------------- CLI
def _cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_cli_convert_both_ways(tmp_path):
    r = _cli("lens", "convert", "cooke-f50", tmp_path / "c.zmx")
    assert r.exit_code == 0, r.output
    assert "EFL 49.9997831 -> 49.9997831 mm" in r.output
    r = _cli("lens", "convert", tmp_path / "c.zmx", tmp_path / "c.json")
    assert r.exit_code == 0, r.output
    _same_optics(Lens.load("cooke-f50"), Lens.load(tmp_path / "c.json"))
    r = _cli("lens", "convert", DATA / "asphere_plastic.zmx", tmp_path / "a16.zmx", "--utf16")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "a16.zmx").read_bytes()[:2] == b"\xff\xfe"
    assert "ignored (no effect on the nominal optics" in r.output


def test_cli_convert_errors(tmp_path):
    r = _cli("lens", "convert", "cooke-f50", tmp_path / "c.txt")
    assert r.exit_code == 2 and "unknown extension '.txt' (use .json or .zmx)" in r.output
    r = _cli("lens", "convert", BROKEN / "unknown_glass.zmx", tmp_path / "x.json")
    assert r.exit_code == 1
    assert "Error: " in r.output and ":93: GLAS: SURF 3: unknown glass 'N-SF111' in the file's catalogs" in r.output
    r = _cli("lens", "convert", BROKEN / "unknown_keyword.zmx", tmp_path / "x.json", "--lenient")
    assert r.exit_code == 0, r.output
    assert "FROB (line 83)" in r.output


def test_cli_commands_take_zmx(tmp_path):
    """LENS arguments accept .zmx (UTF-16 here); the PSF equals the bundled lens's (with the
    file's SK16)."""
    import numpy as np

    ref = cooke_as_the_files_name_it()
    r = _cli("lens", "info", DATA / "cooke_utf16.zmx", "--rings", 4, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["efl_mm"] == pytest.approx(ref.paraxial()["efl_mm"], rel=1e-12)
    (tmp_path / "ref.json").write_text(json.dumps(ref.data))
    outs = []
    for spec in (DATA / "cooke_legacy_wavl.zmx", tmp_path / "ref.json"):
        out = tmp_path / f"{len(outs)}.npy"
        r = _cli(
            "psf", spec, "--field-deg", 14, "--wavelength-nm", 550, "--size", 16, "--pupil-samples", 32, "--out", out
        )
        assert r.exit_code == 0, r.output
        outs.append(np.load(out))
    # radii typed as 16-digit curvatures differ in the last bit; the FFT stage is f32
    assert np.allclose(outs[0], outs[1], rtol=1e-5, atol=1e-6 * outs[1].max())
    r = _cli("lens", "info", tmp_path / "missing.zmx")
    assert r.exit_code == 1 and "missing.zmx: no such lens file" in r.output


def test_every_written_surface_has_a_diam_line_and_the_footprint_clips_nothing(tmp_path):
    # other readers (DeepLens) need a DIAM on every surface, as OpticStudio writes; ours keeps
    # an automatic DIAM as a clear aperture, so the footprint must not vignette any ray
    import numpy as np

    from optix_e2e import _engine

    lens = Lens.load("cooke-f50")
    text = lens.to_zmx()
    surfs = text.split("SURF ")[1:]
    assert len(surfs) == len(lens.surfaces) + 2  # object, body, image
    assert all("  DIAM " in s for s in surfs)
    back = _roundtrip(lens, tmp_path)
    assert all(s.get("semi_diameter") for s in back.data["surfaces"])
    channels = [[(420.0, 1.0)], [(587.6, 1.0)], [(700.0, 1.0)]]  # beyond the lens's 486-656 nm too
    for field in (0.0, max(lens.fields_deg)):
        pa, ria, _ = _engine.psf_rgb(lens.to_engine_json(), field, channels, pixel_um=2.0, size=48)
        pb, rib, _ = _engine.psf_rgb(back.to_engine_json(), field, channels, pixel_um=2.0, size=48)
        np.testing.assert_allclose(pb, pa, atol=1e-12)
        np.testing.assert_allclose(rib, ria, rtol=1e-12)
