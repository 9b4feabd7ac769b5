"""Real OpticStudio files and hostile .zmx input.

The real files are the 640 samples in ../shared/zmx-samples (vendor catalogs and public
repositories, unedited), found like the reference data (conftest.py): <repo>/../shared,
$OPTIX_SHARED_DIR or OPTIX_ZMX_SAMPLES_DIR.  A missing folder is a failure, never a skip.
"""

import math
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import WHERE_SHARED, shared_dir

from optix_e2e.cli import main
from optix_e2e.lens import Lens
from optix_e2e.lens.zemax import ZemaxError, parse_zmx, read_zmx
from optix_e2e.lens.zemax.survey import nominal_focal_length, survey

DATA = Path(__file__).parents[1] / "data" / "zmx"


@pytest.fixture(scope="module")
def samples() -> Path:
    path = shared_dir("zmx-samples", "OPTIX_ZMX_SAMPLES_DIR")
    if not any(path.rglob("*.zmx")):
        pytest.fail(f"no .zmx samples at {path}: {WHERE_SHARED} (or OPTIX_ZMX_SAMPLES_DIR)", pytrace=False)
    return path


# ----------------------------------------------------------------------------- item 4: real files
def test_real_files_import_trace_and_match_their_focal_length(samples):
    """Every sample: rotationally symmetric refractive files import and trace with the EFL
    their catalog entry states; every other file is refused with one line naming its
    feature.  The floor is the issue's target (99 %; measured 99.64 %, docs/zemax.md)."""
    summary, results = survey(samples)
    assert summary["files"] == len(results) >= 600
    target = [r for r in results if r.target]
    assert summary["target_rate"] >= 0.99, summary["target_refused_reasons"]
    # the nominal focal length is checked on hundreds of catalog parts, and all agree
    assert summary["target_with_nominal_efl"] >= 400
    # one known: Thorlabs CFS18-1550-APC names the 780 nm focal length of its lens (18.40;
    # ours there 18.4000) while the file is at 1550 nm (18.79)
    assert summary["efl_mismatches"] == ["zmf_THORLABS/CFS18-1550-APC.zmx: EFL 18.79 vs nominal 18.4"]
    for r in results:
        assert "\n" not in r.error and r.error.count("Traceback") == 0
        if not r.target:  # outside the target set: refused, and the error names the feature
            assert not r.imported, r.file
            assert any(
                w in r.error
                for w in (
                    "toroidal",
                    "mirror",
                    "tilt",
                    "coordinate break",
                    "grating",
                    "Fresnel",
                    "binary",
                    "aperture",
                    "sequential",
                )
            ), r.error
        elif not r.traced:
            assert r.error.startswith(
                ("ZemaxError", "MaterialError", "LensError", "PrescriptionError", "SurfacesCrossError")
            ), r.error
    assert sum(r.traced for r in target) == summary["target_traced"]


def test_nominal_focal_length_from_catalog_text():
    cases = {
        "NAME AC254-200-B AC254-200-B NEAR IR ACHROMATS: Infinite Conjugate 200": 200.0,
        "NAME Mounted Ø=6.33mm, f=4.03mm, NA=0.64 D-ZK3 Asphere,-A": 4.03,
        "NAME 32004\nNOTE 0 15.0mm Dia. x 22.5mm FL Uncoated, Plano-Convex Lens": 22.5,
        "NAME 34620 12.7mm Dia x -100mm FL PCV Cyl Lens": -100.0,
        "NAME 89682 Achromatic Lens\nNOTE 0 LENS ACH 40 x 50 VIS 0 TS": 50.0,
        "NAME 88000\nNOTE 0 LENS PCX ZNSE 25.4 X 50.8MM 8-12UM CTD": 50.8,
        "NAME Pigtail Aspheric Collimator, EFL 2.01, 1030 nm, FC": 2.01,
        "NAME LA1074 Plano-Convex - N-BK7": None,
    }
    for text, want in cases.items():
        assert nominal_focal_length(text) == want, text


HEAD = (
    "VERS 181119\nMODE SEQ\nNAME t\nUNIT MM X W X CM MR CPMM\nENPD 10\nGCAT {gcat}\n"
    "FTYP 0 0 1 1 0 0 0 1\nXFLN 0\nYFLN 0\nFWGN 1\nWAVM 1 {wl} 1\nPWAV 1\n"
)
SINGLET = (
    "SURF 0\n  CURV 0.0\n  DISZ INFINITY\nSURF 1\n  STOP\n  CURV 0.02\n  DISZ 4\n  GLAS {glass}\n"
    '  DIAM 12.7 1 0 0 1 ""\n  OEMA 0.5 0 0 0 0 ""\n  FLAP 0 12.7 0\nSURF 2\n  CURV 0.0\n'
    "  DISZ 95\nSURF 3\n  CURV 0.0\n  DISZ 0\n"
)


def _singlet(glass="N-BK7", gcat="SCHOTT", wl="0.5876"):
    return HEAD.format(gcat=gcat, wl=wl) + SINGLET.format(glass=glass)


def test_opticstudio18_header_and_oema_import():
    """FTYP's 8th number is the field count (not 'afocal'); OEMA is mechanical data."""
    imp = parse_zmx(_singlet(), source="<t>")
    assert imp.data["fields_deg"] == [0.0]
    assert any(k == "OEMA" for _, k, _ in imp.ignored)
    assert imp.data["surfaces"][0]["semi_diameter"] == 12.7


def test_glass_resolves_only_in_the_files_catalogs():
    """BAF2 under INFRARED is the crystal (nd 1.4744, Malitson), under CDGM the glass
    (nd 1.5697): never one for the other; outside the listed catalogs it is an error."""
    crystal = Lens(parse_zmx(_singlet("BAF2", "INFRARED"), source="<t>").data)
    glass = Lens(parse_zmx(_singlet("BAF2", "CDGM"), source="<t>").data)
    assert crystal.refractive_indices(587.5618)[1] == pytest.approx(1.4744, abs=2e-4)
    assert glass.refractive_indices(587.5618)[1] == pytest.approx(1.5697, abs=2e-4)
    with pytest.raises(ZemaxError, match=r"<t>:20: GLAS: SURF 1: unknown glass 'N-SF111'.*GCAT SCHOTT"):
        parse_zmx(_singlet("N-SF111"), source="<t>")
    with pytest.raises(
        ZemaxError,
        match=r"unknown glass 'BAF2' in the file's catalogs \(GCAT SCHOTT\); "
        r"not substituted: BAF2 exists in catalog cdgm",
    ):
        parse_zmx(_singlet("BAF2", "SCHOTT"), source="<t>")


@pytest.mark.parametrize(
    "glass,gcat,wl_um,n_ref",
    [
        # published indices: fused silica and the fluorides (Malitson), BK7 (SCHOTT: nd 1.51680),
        # germanium at 10 um (4.003, Li 1980; sources differ by 1e-3), silicon at 4 um (3.4255), ZnSe at
        # 10.6 um (2.4028, Connolly); Corning 7980's data sheet nd 1.4584
        ("F_SILICA", "SCHOTT INFRARED", 0.5875618, 1.45846),
        ("C79-80", "CORNING", 0.5875618, 1.4584),
        ("CAF2", "SCHOTT CDGM NOA61 MISC", 0.5875618, 1.43385),
        ("BK7", "SCHOTT", 0.5875618, 1.51680),
        ("GERMANIUM", "SCHOTT INFRARED", 10.0, 4.003),
        ("SILICON", "INFRARED", 4.0, 3.4255),
        ("ZNSE", "LIGHTPATH INFRARED", 10.6, 2.4028),
    ],
)
def test_zemax_catalog_names_give_published_indices(glass, gcat, wl_um, n_ref):
    lens = Lens(parse_zmx(_singlet(glass, gcat, wl=str(wl_um)), source="<t>").data)
    tol = 1.5e-3 if glass == "GERMANIUM" else 3e-4
    assert lens.refractive_indices(wl_um * 1000)[1] == pytest.approx(n_ref, abs=tol)


def test_lens_info_takes_lenient(tmp_path):
    path = tmp_path / "odd.zmx"
    path.write_text(_singlet().replace("PWAV 1\n", "PWAV 1\nFROB 1 2\n"))
    r = CliRunner().invoke(main, ["lens", "info", str(path)])
    assert r.exit_code == 1 and "FROB: unknown keyword" in r.output
    r = CliRunner().invoke(main, ["lens", "info", str(path), "--lenient", "--json"])
    assert r.exit_code == 0, r.output


# ----------------------------------------------------------------------------- item 5: bad input
@pytest.mark.parametrize("name", ["cooke-f50", "double-gauss-f5", "paper-triplet"])
def test_every_line_truncation_is_an_error_or_the_same_lens(name):
    """Cutting a file after any line must not give a different lens (double-gauss-f5 cut
    before SURF 7 used to import with EFL 215 mm instead of 100)."""
    full = Lens.load(name)
    lines = full.to_zmx().splitlines(keepends=True)
    efl = full.paraxial()["efl_mm"]
    for cut in range(1, len(lines)):
        try:
            imp = parse_zmx("".join(lines[:cut]), source="<cut>")
        except ZemaxError:
            continue
        got = Lens(imp.data).paraxial()["efl_mm"]
        assert got == efl, f"cut after line {cut}: EFL {got} instead of {efl}"


@pytest.mark.parametrize(
    "edit,msg",
    [
        (("PWAV 1\n", "PWAV 1.5\n"), r"<t>:12: PWAV: primary wavelength must be an integer, got '1\.5'"),
        (("FTYP 0 0 1 1 0 0 0 1", "FTYP 0 0 5 2.5 0 0 0 1"), r"<t>:7: FTYP: wavelength count must be an integer"),
        (("SURF 1\n", "SURF 1.5\n"), r"<t>:16: SURF: surface number must be an integer, got '1\.5'"),
        (("CURV 0.02", "CURV 1e-320"), r"<t>:18: CURV: SURF 1: curvature 1e-320 has no finite radius"),
        (
            ("FTYP 0 0 1 1 0 0 0 1", "FTYP 0 0 1 1e300 0 0 0 1"),
            r"<t>:7: FTYP: wavelength count 1e300 outside 1\.\.1000",
        ),
        (("FTYP 0 0 1 1 0 0 0 1", "FTYP 0 0 1e8 1 0 0 0 1"), r"<t>:7: FTYP: field count 1e8 outside 1\.\.1000"),
        (("WAVM 1 0.5876 1", "WAVM 1e9 0.5876 1"), r"<t>:11: WAVM: wavelength slot 1e9 outside 1\.\.1000"),
        (("  STOP\n", "  STOP\n  PARM 1,5 0\n"), r"<t>:18: PARM: parameter number must be an integer, got '1,5'"),
        (("DIAM 12.7 1 0", "DIAM 12.7 1.5 0"), r"<t>:21: DIAM: DIAM solve flag must be an integer"),
    ],
)
def test_bad_numbers_name_line_and_keyword(edit, msg):
    text = _singlet()
    assert edit[0] in text
    with pytest.raises(ZemaxError, match=msg):
        parse_zmx(text.replace(edit[0], edit[1], 1), source="<t>")


def test_unit_meter_asphere_traces_as_the_scaled_lens():
    """UNIT METER makes the asphere 1000x larger: the spot must scale by 1000 exactly (the
    intersection's Newton tolerance was an absolute 1e-13 mm, below one ulp there)."""
    text = (DATA / "asphere_plastic.zmx").read_text()
    mm = Lens(parse_zmx(text).data)
    m = Lens(parse_zmx(text.replace("UNIT MM", "UNIT METER")).data)
    assert m.paraxial()["efl_mm"] == pytest.approx(1000 * mm.paraxial()["efl_mm"], rel=1e-12)
    for field in (0.0, 10.0):
        a, b = mm.spot(field, rings=8), m.spot(field, rings=8)
        assert b["n_rays"] == a["n_rays"]
        assert math.isfinite(b["rms_um"])
        assert b["rms_um"] == pytest.approx(1000 * a["rms_um"], rel=1e-9)


# ------------------------------------------------- item 4: classes of real files that were refused
def _zmx(surfaces: str, aperture="ENPD 2", gcat="SCHOTT", wl="0.5875618") -> str:
    """A file with the object at infinity, the given lens surfaces (SURF 1..k) and an image."""
    head = HEAD.format(gcat=gcat, wl=wl).replace("ENPD 10\n", aperture + "\n")
    k = surfaces.count("SURF ")
    return head + "SURF 0\n  CURV 0.0\n  DISZ INFINITY\n" + surfaces + f"SURF {k + 1}\n  CURV 0.0\n  DISZ 0\n"


def _ball(radius: float, glass="N-LASF9", last="INFINITY", diam=None) -> str:
    sd = "" if diam is None else f'  DIAM {diam} 1 0 0 1 ""\n'
    return (
        f"SURF 1\n  STOP\n  CURV {1 / radius!r}\n  DISZ {2 * radius!r}\n  GLAS {glass}\n{sd}"
        f"SURF 2\n  CURV {-1 / radius!r}\n  DISZ {last}\n{sd}"
    )


def _ball_efl(lens: Lens, radius: float) -> float:
    """A ball lens's EFL, n D / (4 (n - 1)), measured from its centre."""
    n = lens.refractive_indices(lens.data["primary_wavelength_nm"])[1]
    return n * 2 * radius / (4 * (n - 1))


def test_unknown_glass_with_its_nd_vd_on_the_glas_line_is_a_model_glass():
    """A catalog glass missing from the database but with nd and vd recorded on its GLAS
    line (as OpticStudio writes them) imports, in strict mode, as a model glass, with a note;
    OpticStudio's placeholder (1.5, 40) or no values stay an error that says why.  (LPX550 is
    a made-up name: the LightPath glasses of the sample files are all in the database now.)"""
    text = _zmx(_ball(5, glass="LPX550 0 0 1.6062 60.6 0 0 0 0 0 0", last="5"), gcat="LIGHTPATH")
    imp = parse_zmx(text, source="<t>")
    assert imp.data["surfaces"][0]["material"] == {"nd": 1.6062, "vd": 60.6}
    assert any("LPX550 is not in the glass database" in n and "model glass" in n for n in imp.notes)
    n = Lens(imp.data).refractive_indices
    nd, nf, nc = (n(w)[1] for w in (587.5618, 486.1327, 656.2725))
    assert nd == pytest.approx(1.6062, abs=1e-12) and (nd - 1) / (nf - nc) == pytest.approx(60.6, rel=1e-9)
    with pytest.raises(ZemaxError, match=r"unknown glass 'LPX550'.*OpticStudio's placeholder"):
        parse_zmx(text.replace("1.6062 60.6", "1.5 40"), source="<t>")
    with pytest.raises(ZemaxError, match=r"unknown glass 'LPX550'.*records no nd/vd"):
        parse_zmx(text.replace(" 0 0 1.6062 60.6 0 0 0 0 0 0", ""), source="<t>")


def test_glass_data_just_past_its_range_is_extrapolated_with_a_note():
    """LightPath BD2's data cover 3-14 um; 2.5 um (4.5 % of the span before it) is the
    table's first segment extended, with a note; 1.5 um (14 %) is an error naming the range."""
    from optix_e2e.lens.glass import resolve

    table = resolve("BD2", "lightpath").tabulated
    (w0, n0), (w1, n1) = table[0], table[1]
    text = _zmx(_ball(5, glass="BD2", last="5"), gcat="LIGHTPATH", wl="2.5")
    imp = parse_zmx(text, source="<t>")
    assert any("BD2 (lightpath): data cover 3000-14000 nm; 2500 nm extrapolated" in n for n in imp.notes)
    got = Lens(imp.data).refractive_indices(2500.0)[1]
    assert got == pytest.approx(n0 + (2.5 - w0) * (n1 - n0) / (w1 - w0), abs=1e-12)
    far = Lens(parse_zmx(text.replace("WAVM 1 2.5", "WAVM 1 1.5"), source="<t>").data)
    from optix_e2e._engine import MaterialError

    with pytest.raises(
        MaterialError,
        match=r"1500\.0 nm is outside the table 3000\.0-14000\.0 nm "
        r"\(extrapolated at most 10% of the span, to 1900\.0-15100\.0 nm\)",
    ):
        far.paraxial()


def test_floating_aperture_without_value_or_diam_clips_nothing():
    """FLAP 0 0 with no DIAM follows OpticStudio's automatic semi-diameter: no clear aperture."""
    text = _singlet().replace("  DISZ 95\n", "  DISZ 95\n  FLAP 0 0 0\n")
    imp = parse_zmx(text, source="<t>")
    assert "semi_diameter" not in imp.data["surfaces"][1]
    assert any("FLAP" in n and "no clear aperture" in n for n in imp.notes)
    assert Lens(imp.data).paraxial()["efl_mm"] == pytest.approx(
        Lens(parse_zmx(_singlet(), source="<t>").data).paraxial()["efl_mm"], rel=1e-15
    )


@pytest.mark.parametrize("radius", [1.25, 2.5, 3.0, 4.0, 5.0, 10.0])
def test_ball_lens_with_image_at_infinity_and_clear_radius_equal_to_its_radius(radius):
    """Half-ball and ball lenses: DIAM = R (refused at R = 2.5, 5, 10 by rounding) and an image
    at infinity (DISZ INFINITY on the last surface), put at the paraxial focus, f - R behind
    the ball, with f = n D / (4 (n - 1))."""
    imp = parse_zmx(_zmx(_ball(radius, diam=radius)), source="<t>")
    lens = Lens(imp.data)
    f = _ball_efl(lens, radius)
    par = lens.paraxial()
    assert par["efl_mm"] == pytest.approx(f, rel=1e-12)
    assert lens.data["surfaces"][-1]["thickness"] == pytest.approx(f - radius, rel=1e-12)
    assert par["back_focus_shift_mm"] == pytest.approx(0.0, abs=1e-12)
    assert any("image at infinity" in n for n in imp.notes)
    assert lens.spot(0.0, rings=4)["n_rays"] > 0


def test_afocal_window_floating_by_its_stop_imports_with_infinite_efl():
    """A flat window with FLOA (catalog windows): the EPD is the stop's diameter, the EFL is
    infinite, and real rays trace (they leave parallel to how they came)."""
    import numpy as np

    window = (
        'SURF 1\n  CURV 0.0\n  DISZ 4\n  GLAS N-BK7\n  DIAM 11.25 1 0 0 1 ""\n  FLAP 0 11.25 0\n'
        'SURF 2\n  STOP\n  CURV 0.0\n  DISZ 0\n  DIAM 11.25 1 0 0 1 ""\n  FLAP 0 11.25 0\n'
    )
    imp = parse_zmx(
        _zmx(window, aperture="FLOA").replace("YFLN 0", "YFLN 0 5").replace("FTYP 0 0 1 1", "FTYP 0 0 2 1"),
        source="<t>",
    )
    lens = Lens(imp.data)
    par = lens.paraxial()
    assert imp.data["aperture"] == {"type": "epd", "value": 22.5}
    assert math.isinf(par["efl_mm"]) and math.isinf(par["f_number"])
    r = lens.trace_field(5.0, np.array([0.0, 0.0]), np.array([0.0, 0.9]), aiming="real")
    assert list(r["status"]) == [0, 0]
    t = math.radians(5.0)
    assert np.allclose(r["direction"], [0.0, math.sin(t), math.cos(t)], atol=1e-14)


def test_diams_that_make_surfaces_cross_are_dropped_with_a_note():
    """A DIAM does not clip in OpticStudio: where two surfaces would cross inside their
    DIAMs (a drawing size), those semi-diameters are dropped and the beam decides."""
    pair = (
        'SURF 1\n  STOP\n  CURV 0.05\n  DISZ 3\n  GLAS N-BK7\n  DIAM 4 1 0 0 1 ""\n'
        'SURF 2\n  CURV 0.1\n  DISZ 1\n  GLAS N-SF5\n  DIAM 4 1 0 0 1 ""\n'
        'SURF 3\n  CURV -0.1\n  DISZ 20\n  DIAM 4 1 0 0 1 ""\n'
    )  # cross at r ~ 3.2
    imp = parse_zmx(_zmx(pair), source="<t>")
    s = imp.data["surfaces"]
    assert "semi_diameter" not in s[1] and "semi_diameter" not in s[2] and s[0]["semi_diameter"] == 4
    from optix_e2e._engine import LensError

    with pytest.raises(LensError, match="surfaces 2 and 3 cross"):  # as read before: an error
        Lens({**imp.data, "surfaces": [s[0], {**s[1], "semi_diameter": 4}, {**s[2], "semi_diameter": 4}]}).paraxial()
    assert any("surfaces 2 and 3 would cross inside their DIAMs" in n for n in imp.notes)
    Lens(imp.data).paraxial()


def test_parameter_and_conic_pickups_import_the_values_written_with_them(samples):
    """Edmund's 83616 (an asphere whose back surface picks up the front one's PARM values
    with scale -1, PPAR, and its conic, PKUP) imports in strict mode; the pickups agree with
    the written values and are listed. A hand-edited PARM that disagrees is noted; a pickup
    on a parameter the surface does not give is an error naming the line."""
    path = samples / "zmf_Edmund_Optics_2019" / "83616.zmx"
    imp = read_zmx(path)
    assert "parameter pickup solve (agrees" in imp.ignored_summary()
    assert "conic pickup solve" in imp.ignored_summary()
    s1, s2 = imp.data["surfaces"][0], imp.data["surfaces"][1]
    assert s2["aspheric"] == {k: -v for k, v in s1["aspheric"].items()}
    text = path.read_text(encoding="latin-1")
    edited = text.replace("PARM 3 0.00019956902508819999", "PARM 3 0.0002", 1)
    imp2 = parse_zmx(edited, source="<t>")
    assert any(
        "PPAR picks up 0.000199569025088 for parameter 3" in n and "PARM 3 holds 0.0002" in n for n in imp2.notes
    )
    assert imp2.data["surfaces"][1]["aspheric"]["a6"] == pytest.approx(0.0002)
    with pytest.raises(
        ZemaxError,
        match=r"<t>:\d+: PPAR: SURF 2: pickup solve on parameter 3, but the "
        r"surface has no PARM 3 line",
    ):
        parse_zmx(text.replace("PARM 3 0.00019956902508819999\n", "", 1), source="<t>")


def test_curved_image_with_paraxial_image_height_fields(samples):
    """Edmund's AC-069 (68146): a curved image surface (CURV -0.1675 on the last SURF) and
    fields given as paraxial image heights (FTYP 2, 0 and 0.25 mm). It imports in strict mode
    with image.radius = 1/c, its field angle puts the paraxial image point at 0.25 mm, and
    the real chief ray ends on the sphere near there."""
    import numpy as np

    lens = Lens.from_file(samples / "zmf_Edmund_Optics_2019" / "68146.zmx")
    assert lens.data["image"]["radius"] == pytest.approx(-1 / 0.1675117441171350974, rel=1e-12)
    assert lens.paraxial()["paraxial_image_height_mm"] == pytest.approx(0.25, rel=1e-9)
    assert any("paraxial image-height fields 0, 0.25 -> field angles" in n for n in lens.zemax_import.notes)
    hit = lens.trace_field(lens.max_field_deg, np.zeros(1), np.zeros(1))["position"][0]
    z_vertex, radius = lens.paraxial()["image_z_mm"], lens.data["image"]["radius"]
    centre = np.array([0.0, 0.0, z_vertex + radius])
    assert np.linalg.norm(hit - centre) == pytest.approx(abs(radius), abs=1e-9)
    assert hit[1] == pytest.approx(0.25, abs=2e-3)
