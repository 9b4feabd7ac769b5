"""TOML parameter spaces (optix_e2e.lens_design.space): the bundled ones, the file format and its errors,
and the aperture kinds."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from optix_e2e.lens import Lens, bundled_lenses
from optix_e2e.lens_design.space import ParameterSpace, SpaceError, bundled_spaces, load_space, parameter_from_name


def test_every_bundled_lens_ships_a_space_containing_it():
    # one space per lens, named after it; other spaces (paper-triplet-e2e, -detect, -wide,
    # -detect-wide) are around a bundled lens
    assert set(bundled_lenses()) <= set(bundled_spaces())
    assert set(bundled_spaces()) - set(bundled_lenses()) == {
        "paper-triplet-e2e",
        "paper-triplet-detect",
        "paper-triplet-wide",
        "paper-triplet-detect-wide",
    }
    for name in bundled_spaces():
        space, lens = load_space(name)
        assert lens.name == (name if name in bundled_lenses() else "paper-triplet")
        assert space.check_bounds(lens.data) == []
        for p in space.params:  # every range is a real interval around the nominal
            assert p.min < p.get(lens.data) < p.max or p.min <= p.get(lens.data) <= p.max


def test_toml_round_trip(tmp_path):
    space, lens = load_space("paper-triplet")
    out = tmp_path / "copy.toml"
    space.save_toml(out)
    again = ParameterSpace.load(out)
    assert again.params == space.params
    assert again.notes == space.notes and again.lens_ref == "paper-triplet"
    assert again.base_lens().data == lens.data


def test_relative_base_lens_path(tmp_path):
    (tmp_path / "my.json").write_text(Lens.load("cooke-f50").to_engine_json())
    (tmp_path / "s.toml").write_text(
        'lens = "my.json"\n[[parameter]]\nname = "s_1_radius"\n'
        'kind = "radius"\nsurface = 1\nmin = 21.0\nmax = 23.0\nunit = "mm"\n'
    )
    space, lens = load_space(tmp_path / "s.toml")
    assert lens.surfaces[0]["radius"] == pytest.approx(22.01359)


@pytest.mark.parametrize(
    "body, msg",
    [
        (
            'lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "radius"\nsurface = 1\nmin = 30\nmax = 20\n',
            r"\[\[parameter\]\] #1 \(a\): min 30 must be < max 20",
        ),
        (
            'lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "radius"\nsurface = 1\nmin = 20\nmax = 30\nunit = "um"\n',
            r"#1 \(a\): unit 'um' for kind radius; expected 'mm'",
        ),
        (
            'lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "thickness"\nsurface = 1\nmin = 0\nmax = 3\n',
            r"thickness must stay positive",
        ),
        (
            'lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "f_number"\nsurface = 2\nmin = 4\nmax = 6\n',
            r"aperture parameter \(f_number\) has surface = 0",
        ),
        (
            'lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "radius"\nsurface = 1\nmin = 20\n',
            r"#1: missing 'max'",
        ),
        ('lens = "cooke-f50"\nranges = 3\n', r"unknown top-level key\(s\) ranges"),
        ('lens = "cooke-f50"\n', r"no parameters"),
        ('lens = "cooke-f50"\n[[parameter]\n', r"s\.toml: invalid TOML: .*line 2"),
    ],
)
def test_toml_errors_name_file_and_entry(tmp_path, body, msg):
    f = tmp_path / "s.toml"
    f.write_text(body)
    with pytest.raises(SpaceError, match=msg):
        ParameterSpace.load(f)


def test_base_lens_problems(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('lens = "no-such-lens"\n[[parameter]]\nname = "a"\nkind = "radius"\nsurface = 1\nmin = 20\nmax = 30\n')
    with pytest.raises(SpaceError, match=r"s\.toml: base lens 'no-such-lens'"):
        load_space(f)
    f.write_text('lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "radius"\nsurface = 9\nmin = 20\nmax = 30\n')
    with pytest.raises(SpaceError, match=r"parameter\(s\) a name a surface beyond the base lens's 6 surfaces"):
        load_space(f)
    f.write_text('lens = "cooke-f50"\n[[parameter]]\nname = "a"\nkind = "radius"\nsurface = 1\nmin = 30\nmax = 40\n')
    with pytest.raises(SpaceError, match=r"base lens lies outside the space: a = 22.0136 outside \[30, 40\]"):
        load_space(f)
    with pytest.raises(SpaceError, match=r"neither a space file nor a bundled lens with a space"):
        load_space("nothing-here")


def test_aperture_kinds():
    cooke = Lens.load("cooke-f50")  # aperture given as EPD 10 mm
    p = parameter_from_name("epd", cooke.data)
    assert (p.kind, p.surface, p.min, p.max) == ("epd", 0, 8.0, 12.5)
    sp = ParameterSpace([p])
    new = Lens(sp.apply(cooke.data, [8.0]))
    assert new.paraxial()["epd_mm"] == pytest.approx(8.0, rel=1e-9)
    with pytest.raises(SpaceError, match=r"aperture is given as 'epd', not 'fno'"):
        parameter_from_name("f_number", cooke.data)
    fno = ParameterSpace([parameter_from_name("f_number", Lens.load("paper-triplet").data)])
    faster = Lens(fno.apply(Lens.load("paper-triplet").data, [3.2]))
    assert faster.paraxial()["f_number"] == pytest.approx(3.2, rel=1e-9)


def test_wide_space_has_table_1s_relative_widths_and_is_what_its_script_makes(tmp_path):
    import subprocess
    import sys

    space, lens = load_space("paper-triplet-wide")
    e2e, _ = load_space("paper-triplet-e2e")
    assert space.names == e2e.names and space.constraints == e2e.constraints
    v = dict(zip(space.names, space.values(lens.data)))
    p = {q.name: q for q in space.params}
    # Table 1: s_1_radius 9.85 .. 14.98 mm is +-20.7 % of its mid-range value
    for name, rel in (("s_1_radius", 2.565 / 12.415), ("s_2_radius", 2.685 / 12.135), ("s_7_radius", 1.775 / 13.275)):
        half = (p[name].max - p[name].min) / 2
        assert half / abs(v[name]) == pytest.approx(rel, rel=1e-4)
    assert (p["s_1_conic"].max - p["s_1_conic"].min) / 2 == pytest.approx(0.39, rel=1e-4)
    assert p["l_12"].max - v["l_12"] == pytest.approx(v["l_12"] * 2.765 / 7.345, rel=1e-4)
    assert p["l_2STO"].min == 0.0  # +-80 % of max(0.14 mm, 1 mm), floored at 0
    for q, e in zip(space.params, e2e.params):  # every range at least as wide as the end-to-end space's
        assert q.min <= e.min and q.max >= e.max, q.name
    out = tmp_path / "wide.toml"
    subprocess.run(
        [sys.executable, "scripts/paper_width_space.py", "--out", str(out)],
        check=True,
        capture_output=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert ParameterSpace.load(out).params == space.params


def test_detection_wide_space_holds_a_manufacturable_f3_2_lens():
    """The detection space (issue 35): the paper-width space plus lens 1's and lens 3's centre
    thicknesses and the aperture, same limits. An f/3.2 lens found in it by
    benches/fast_lens_search.py (tests/data/lenses/detect_wide_f3.2.json) lies inside its ranges
    and passes the one constraint definition at its own clear apertures; the nominal opened to
    f/3.2 as it is does not (its lens-2-to-stop gap crosses the wider beam)."""
    import copy
    import json

    from optix_e2e.lens_design.constraints import Limits, check_design, own_apertures

    space, base = load_space("paper-triplet-detect-wide")
    wide, _ = load_space("paper-triplet-wide")
    assert space.names == wide.names + ["s_1_thickness", "s_6_thickness", "f_number"]
    assert space.params[: len(wide)] == wide.params and space.constraints == wide.constraints
    kinds = {q.name: (q.kind, q.surface, q.min, q.max) for q in space.params}
    assert kinds["s_1_thickness"] == ("thickness", 1, 2.0, 8.0) and kinds["s_6_thickness"] == ("thickness", 6, 2.0, 8.0)
    assert kinds["f_number"] == ("f_number", 0, 2.8, 4.6)
    assert space.check_bounds(base.data) == []  # the nominal is inside

    raw = json.loads((Path(__file__).parents[1] / "data" / "lenses" / "detect_wide_f3.2.json").read_text())
    fast = Lens(raw)
    limits = Limits.from_dict(space.constraints)
    assert fast.paraxial()["f_number"] == pytest.approx(3.2, rel=1e-3)
    assert fast.paraxial()["efl_mm"] == pytest.approx(25.0, rel=1e-3)
    assert space.check_bounds(fast.data) == []
    assert check_design(fast.data, own_apertures(fast.data), limits) == []

    opened = copy.deepcopy(base.data)
    opened["aperture"] = {"type": "fno", "value": 3.2}
    for s in opened["surfaces"]:
        s.pop("semi_diameter", None)
    with pytest.raises(Exception, match="cross"):
        Lens(opened)


def test_with_ranges_keeps_everything_but_the_ranges():
    space, _ = load_space("paper-triplet-e2e")
    wide = space.with_ranges([(p.min - 1, p.max + 1.23456789) for p in space.params], source="x.toml")
    assert wide.names == space.names and wide.notes == space.notes and wide.constraints == space.constraints
    assert wide.lens_ref == space.lens_ref and wide.source == "x.toml"
    assert wide.params[0].max == float(f"{space.params[0].max + 1.23456789:.6g}")
    with pytest.raises(SpaceError, match="2 ranges for 19 parameters"):
        space.with_ranges([(0, 1), (0, 1)], source="x.toml")


@pytest.mark.parametrize(
    "old, new, words",
    [
        ("[constraints]\n", "[constraints]\nmin_bdf = 12.0\n", "unknown constraint(s) min_bdf"),
        ("min_bfd = 10.0", 'min_bfd = "abc"', "min_bfd must be"),
    ],
)
def test_a_space_files_bad_constraint_is_refused_where_it_is_read(tmp_path, old, new, words):
    """A misspelt or non-numeric limit in [constraints] was ignored by ``optix design --space``
    and refused by ``optix sample``: every command reads the file through load_space, which now
    refuses it, naming the file."""
    text = (Path(load_space("paper-triplet")[0].source)).read_text()
    bad = tmp_path / "bad.toml"
    assert old in text
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(SpaceError, match=re.escape(words)) as err:
        load_space(str(bad))
    assert str(bad) in str(err.value)


@pytest.mark.parametrize(
    "old, new, words",
    [
        ('kind = "radius"', 'kind = ["radius"]', "kind ['radius'] is not one of"),
        ('name = "s_1_radius"', 'name = ["s_1_radius"]', "name must be a text"),
        ("[constraints]\n", "deep = " + "[" * 20000 + "]" * 20000 + "\n[constraints]\n", "nested too deeply"),
    ],
)
def test_a_space_file_of_the_wrong_shape_is_one_error(tmp_path, old, new, words):
    """A list where a name or a kind belongs, arrays nested 20,000 deep: one SpaceError naming the
    file (were a TypeError and a RecursionError traceback in design, sample and dataset)."""
    text = Path(load_space("paper-triplet")[0].source).read_text()
    assert old in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(SpaceError, match=re.escape(words)) as err:
        load_space(str(bad))
    assert str(bad) in str(err.value)
