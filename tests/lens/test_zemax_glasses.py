"""Zemax catalog glasses the database lacks, built in from Zemax's AGF catalog data
(optix_e2e.lens.glass.ZEMAX_NAMES): LightPath's ECO550 family, C0550, PBH71 and its molded
CDGM glasses, RPO's molded glasses, the withdrawn Schott BAFN11 and K3, and MISC's ACRYLIC.

The reference nd and vd are the ones each AGF file states on the glass's NM line, numbers
published independently of the dispersion coefficients that were copied from its CD line.
"""

import pytest

from optix_e2e.lens import Lens, glass
from optix_e2e.lens.zemax import ZemaxError, parse_zmx

D, F, C = 0.5875618, 0.4861327, 0.6562725  # um

# (catalog, name, nd, vd) from the NM lines of Zemax's LIGHTPATH, RPO, SCHOTT (2008, with
# the obsolete glasses) and MISC catalogs
AGF_ND_VD = [
    ("lightpath", "ECO550", 1.605503, 50.277746),
    ("lightpath", "ECO550M", 1.602897, 50.021894),
    ("lightpath", "ECO550_E", 1.600348, 47.142136),
    ("lightpath", "C0550", 1.605004, 50.419332),
    ("lightpath", "PBH71", 1.922864, 21.288699),
    ("lightpath", "D-ZK3M", 1.586420, 60.713872),
    ("lightpath", "D-ZLAF52LAM", 1.805885, 40.792034),
    ("lightpath", "D-ZLAF52LA_M", 1.805881, 40.888056),
    ("rpo", "D-LAK6_MOLD", 1.689442, 52.830176),
    ("rpo", "H-LAK54_MOLD", 1.728497, 51.102214),
    ("schott", "BAFN10", 1.670031, 47.108735),
    ("schott", "BAFN11", 1.666721, 48.421391),
    ("schott", "K3", 1.518230, 58.976559),
    ("misc", "ACRYLIC", 1.491668, 55.310192),
]


@pytest.mark.parametrize("catalog, name, nd, vd", AGF_ND_VD)
def test_builtin_glass_matches_its_agf_nd_and_vd(catalog, name, nd, vd):
    g = glass.resolve(name, catalog)
    assert (g.name, g.catalog) == (name, catalog) and g.path == f"builtin:{catalog}/{name}"
    n_d, n_f, n_c = (float(g.n(w)) for w in (D, F, C))
    assert n_d == pytest.approx(nd, abs=1e-5)
    assert (n_d - 1) / (n_f - n_c) == pytest.approx(vd, abs=0.05)
    lo, hi = g.range_um
    assert lo < F < C < hi


@pytest.mark.parametrize("catalog, name, nd, vd", AGF_ND_VD)
def test_engine_evaluates_the_builtin_formula_as_numpy_does(catalog, name, nd, vd):
    """The engine gets the formula as is (formula 3 with 11 coefficients, or formula 2)."""
    g = glass.resolve(name, catalog)
    assert g.to_engine()["formula"] in (2, 3)
    lens = Lens(
        {
            "name": "singlet",
            "units": "mm",
            "aperture": {"type": "epd", "value": 2.0},
            "fields_deg": [0.0],
            "wavelengths_nm": [486.1327, 587.5618, 656.2725],
            "primary_wavelength_nm": 587.5618,
            "surfaces": [
                {"radius": 50.0, "thickness": 3.0, "material": {"glass": name, "catalog": catalog}, "stop": True},
                {"radius": -50.0, "thickness": 45.0, "material": "air"},
            ],
        }
    )
    for w in (F, D, C):
        assert lens.refractive_indices(w * 1000)[1] == pytest.approx(float(g.n(w)), abs=1e-12)
    assert lens.refractive_indices(D * 1000)[1] == pytest.approx(nd, abs=1e-5)


@pytest.mark.parametrize(
    "name, catalog, also_in",
    [
        ("ECO550", "lightpath", set()),
        ("ECO550M", "lightpath", set()),
        ("ECO550_E", "lightpath", set()),
        ("D-ZK3M", "lightpath", set()),
        ("H-LAK54_MOLD", "rpo", set()),
        ("BAFN11", "schott", set()),
        ("K3", "schott", {"hikari"}),  # Hikari's K3 is its own glass
    ],
)
def test_zemax_names_resolve_only_under_their_catalog(name, catalog, also_in):
    assert glass.resolve(name, catalog).catalog == catalog
    for other in set(glass.catalogs()) - {catalog} - also_in:
        with pytest.raises(glass.GlassError, match=f"it exists in: .*{catalog}"):
            glass.resolve(name, other)


def test_acrylic_is_zemax_data_under_misc_and_pmma_otherwise():
    """MISC's ACRYLIC is Zemax's formula (nd 1.491668); a bare "acrylic" keeps meaning
    the database's PMMA (1.05e-3 lower at the d line), as JSON lens files use it."""
    assert glass.resolve("ACRYLIC", "misc").n(D) == pytest.approx(1.491668, abs=1e-6)
    for bare in ("acrylic", "ACRYLIC"):
        assert glass.resolve(bare).label == "PMMA (organic)"
    assert glass.resolve("acrylic", "organic").label == "PMMA (organic)"


def test_molded_glasses_have_the_molders_index_below_the_annealed_cdgm_glass():
    """Molding lowers the index a few 1e-3: the molder's data, not CDGM's annealed data."""
    for molded, catalog, annealed in [
        ("D-ZK3M", "lightpath", "D-ZK3"),
        ("D-ZLAF52LAM", "lightpath", "D-ZLAF52LA"),
        ("D-ZLAF52LA_M", "lightpath", "D-ZLAF52LA"),
        ("D-LAK6_MOLD", "rpo", "D-LAK6"),
        ("H-LAK54_MOLD", "rpo", "H-LAK54"),
    ]:
        drop = glass.resolve(annealed, "cdgm").n(D) - glass.resolve(molded, catalog).n(D)
        assert 2e-3 < drop < 6e-3, molded


# ----------------------------------------------------------------------- through a .zmx file
HEAD = (
    "VERS 181119\nMODE SEQ\nNAME t\nUNIT MM X W X CM MR CPMM\nENPD 2\nGCAT {gcat}\n"
    "FTYP 0 0 1 1 0 0 0 1\nXFLN 0\nYFLN 0\nFWGN 1\nWAVM 1 0.5875618 1\nPWAV 1\n"
    "SURF 0\n  CURV 0.0\n  DISZ INFINITY\nSURF 1\n  STOP\n  CURV 0.02\n  DISZ 3\n  GLAS {glass}\n"
    "SURF 2\n  CURV -0.02\n  DISZ 45\nSURF 3\n  CURV 0.0\n  DISZ 0\n"
)


@pytest.mark.parametrize(
    "glas, gcat, want",
    [
        ("ECO550", "SCHOTT LIGHTPATH", ("ECO550", "lightpath")),
        ("ECO550M", "SCHOTT LIGHTPATH", ("ECO550M", "lightpath")),
        ("ECO550_E", "LIGHTPATH SCHOTT", ("ECO550_E", "lightpath")),
        ("K3", "SCHOTT LIGHTPATH", ("K3", "schott")),
        ("BAFN11", "SCHOTT INFRARED MISC", ("BAFN11", "schott")),
        ("D-ZK3M", "SCHOTT LIGHTPATH", ("D-ZK3M", "lightpath")),
        ("ACRYLIC", "SCHOTT MISC", ("ACRYLIC", "misc")),
        ("PMMA", "SCHOTT MISC", ("PMMA", "organic")),
        ("POLYCARB", "MISC", ("polycarbonate", "organic")),
    ],
)
def test_glas_lines_resolve_in_the_files_catalogs(glas, gcat, want):
    imp = parse_zmx(HEAD.format(gcat=gcat, glass=glas), source="<t>")
    m = imp.data["surfaces"][0]["material"]
    assert (m["glass"], m["catalog"]) == want
    assert not any("molded" in n for n in imp.notes)


def test_glas_line_outside_the_catalog_that_has_the_glass_is_an_error():
    with pytest.raises(
        ZemaxError,
        match=r"unknown glass 'ECO550' in the file's catalogs \(GCAT SCHOTT\); "
        r"not substituted: ECO550 exists in catalog lightpath",
    ):
        parse_zmx(HEAD.format(gcat="SCHOTT", glass="ECO550"), source="<t>")
    with pytest.raises(ZemaxError, match=r"unknown glass 'K3' in the file's catalogs \(GCAT LIGHTPATH\)"):
        parse_zmx(HEAD.format(gcat="LIGHTPATH", glass="K3"), source="<t>")


@pytest.mark.parametrize(
    "glas, gcat, want",
    [
        ("E-LAK7R", "HIKARI", ("J-LAK7R", "hikari")),  # Hikari's E- series became J-
        ("E-FD1R", "HOYA", ("E-FD1", "hoya")),  # a variant mark on a Hoya name
    ],
)
def test_an_older_catalog_name_without_nd_vd_imports_as_its_successor_with_a_note(glas, gcat, want):
    """A glass that neither the database nor the vendors' AGF catalogs have, on a GLAS line
    without usable nd/vd (OpticStudio's placeholder 1.5, 40), imports as the same vendor's
    renamed glass, and the note names both and the indices used."""
    imp = parse_zmx(HEAD.format(gcat=gcat, glass=f"{glas} 0 0 1.5 40"), source="<t>")
    m = imp.data["surfaces"][0]["material"]
    assert (m["glass"], m["catalog"]) == want
    note = next(n for n in imp.notes if "newer name for it or another vendor's equivalent" in n)
    assert f"glass {glas} (line" in note and f"imported as {want[0]} ({want[1]}, nd 1." in note


@pytest.mark.parametrize(
    "glas, gcat, nd",
    [
        ("LAKN7", "SCHOTT", 1.6516),
        ("SSKN5", "SCHOTT OHARA", 1.65844),
        ("F1", "SCHOTT", 1.625882),
        ("SK16", "SCHOTT", 1.62041),
        ("KZFSN2", "SCHOTT", 1.558361),
        ("FD1", "HOYA", 1.71736),
    ],
)
def test_withdrawn_vendor_glasses_import_with_the_vendors_own_data(glas, gcat, nd):
    """Schott's and Hoya's withdrawn glasses (LaKN7, SSKN5, F1, SK16 ...) resolve under their
    catalog to the vendor's AGF data (bundled/glass/agf_glasses.json), no substitution, and the
    engine gives the catalog's nd."""
    imp = parse_zmx(HEAD.format(gcat=gcat, glass=f"{glas} 0 0 1.5 40"), source="<t>")
    m = imp.data["surfaces"][0]["material"]
    assert m["glass"] == glas and not any("equivalent" in n for n in imp.notes)
    assert Lens(imp.data).refractive_indices(587.5618)[1] == pytest.approx(nd, abs=1e-5)


def test_every_agf_glass_gives_its_catalogs_nd_and_vd():
    """Each bundled AGF entry, evaluated by the package, against the nd and vd of its NM line
    (1e-4 and 0.5: the catalogs round vd by up to 0.2); none shadows a database page."""
    from optix_e2e.lens.zemax.reader import _nd_vd

    table = glass._agf_glasses()
    assert sum(len(v) for v in table.values()) > 400
    for catalog, names in table.items():
        for name, e in names.items():
            g = glass.resolve(name, catalog)
            assert g.path == f"builtin:{catalog}/{name}"
            if e["nd"] == 1.0 and e["vd"] == 0.0:  # an infrared material without d-line data (below)
                continue
            nd, vd = _nd_vd(g)
            assert abs(nd - e["nd"]) <= 1e-4 and abs(vd - e["vd"]) <= 0.5, (catalog, name)


@pytest.mark.parametrize(
    "catalog, name, page, wavelengths_um, tol",
    [
        # Zemax INFRARED's ZNS_IR (Herzberger) against Debenham's ZnS (Sellmeier), 4-12 um
        ("infrared", "ZNS_IR", "main/ZnS/nk/Debenham.yml", (4.0, 8.0, 12.0), 2e-3),
        # ZEON's E48R (Zemax ZEON catalog) against Sultanova's measurement of Zeonex E48R
        ("zeon", "E48R", "other/commercial polymers/ZeonexE48R/nk/Sultanova.yml", (0.48, 0.5876, 0.656), 2e-3),
    ],
)
def test_catalog_materials_agree_with_an_independent_measurement(catalog, name, page, wavelengths_um, tol):
    """The AGF data of an infrared crystal and a cyclo-olefin polymer (bundled/glass/agf_glasses.json,
    scripts/agf_glasses.py) against the refractiveindex.info database's page of the same material,
    measured by others (the tolerance: what two measurements of one material differ by)."""
    ours, theirs = glass.resolve(name, catalog), glass._load_page(name, catalog, page)
    for w in wavelengths_um:
        assert float(ours.n(w)) == pytest.approx(float(theirs.n(w)), abs=tol), w


@pytest.mark.parametrize(
    "glas, gcat, want, nd",
    [
        ("S-NPH1_MOLD", "RPO", "rpo", 1.797889),  # RPO's moulded S-NPH1 (S-NPH1 itself: 1.80809)
        ("D-K59_MOLD", "RPO CDGM", "rpo", None),
        ("E48R", "ZEON", "zeon", 1.531160),
        ("480R", "SCHOTT ZEON", "zeon", 1.525279),
    ],
)
def test_moulded_glasses_and_polymers_import_with_the_makers_data(glas, gcat, want, nd):
    """A GLAS line without nd/vd naming a moulded glass (RPO's *_MOLD) or a ZEON polymer under its
    catalog resolves to that catalog's AGF data, no substitution."""
    imp = parse_zmx(HEAD.format(gcat=gcat, glass=f"{glas} 0 0 0 0"), source="<t>")
    m = imp.data["surfaces"][0]["material"]
    assert (m["glass"], m["catalog"]) == (glas, want) and not imp.notes
    if nd is not None:
        assert Lens(imp.data).refractive_indices(587.5618)[1] == pytest.approx(nd, abs=1e-5)


def test_successor_names_stay_inside_the_vendors_renaming():
    from optix_e2e.lens.zemax.glass_names import successor_names

    assert successor_names("LAKN77", "schott") == [
        ("LAKN77", "hikari"),
        ("N-LAKN77", "schott"),
        ("N-LAK77", "schott"),
        ("LAK77", "schott"),
    ]
    assert successor_names("E-LAK7R", "hikari")[:3] == [
        ("J-LAK7R", "hikari"),
        ("LAK7R", "hikari"),
        ("J-LAK7", "hikari"),
    ]
    assert successor_names("K3", "lightpath") == []  # no known renaming: no guess
    # a name the catalog has under no successor stays an error that says why
    with pytest.raises(ZemaxError, match=r"unknown glass 'QQ99'.*records no nd/vd|unknown glass 'QQ99'.*placeholder"):
        parse_zmx(HEAD.format(gcat="SCHOTT", glass="QQ99 0 0 1.5 40"), source="<t>")


@pytest.mark.parametrize("name", ["F2", "SF1", "SK16"])
def test_hikaris_classic_names_match_schotts_indices(name):
    """Hikari's glasses under Schott's classic names are Schott's: nd within 1e-4 and vd
    within 0.1 of Schott's glass of that name (N-SK16 for SK16, which Schott renamed)."""
    from optix_e2e.lens.zemax.reader import _nd_vd

    schott = glass.resolve(name if name != "SK16" else "N-SK16", "schott")
    (nd_s, vd_s), (nd_h, vd_h) = _nd_vd(schott), _nd_vd(glass.resolve(name, "hikari"))
    assert abs(nd_h - nd_s) < 1e-4 and abs(vd_h - vd_s) < 0.1
