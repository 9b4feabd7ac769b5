"""Shared parts of the .zmx reader and writer: keyword classes, unit scales, the error
and the import report."""

from __future__ import annotations

from dataclasses import dataclass, field

from ...errors import InputError

#: Lens units -> millimetres (the UNIT line's first token).
UNITS_MM = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "METER": 1000.0, "M": 1000.0}
#: Keywords that do not change the nominal optics: listed in the report, then skipped.
IGNORED = {
    # header: file/version/UI state, analysis defaults, ray-aiming and polarization settings
    "VERS",
    "NOTE",
    "AUTH",
    "IWDP",
    "PFIL",
    "LANG",
    "GFAC",
    "RAIM",
    "PUSH",
    "SDMA",
    "OMMA",
    "ROPD",
    "HYPR",
    "PICB",
    "POLS",
    "GLRS",
    "GSTD",
    "NSCD",
    "COFN",
    "LUID",
    "BLNK",
    "TOL",
    "MOFF",
    "FWGN",
    "FWGT",
    "VDXN",
    "VDYN",
    "VCXN",
    "VCYN",
    "VANN",
    "CONF",
    "DMFS",
    "SUMM",
    # surface: drawing, slabs, physical-optics settings, mechanical size, coating (transmission)
    "HIDE",
    "MIRR",
    "SLAB",
    "POPS",
    "MEMA",
    "COAT",
    "FIMP",
    "MAZH",
    "DIAZ",
    # tolerancing data, displayed EFL, glass-catalog cache
    "TOLE",
    "EFFL",
    "GLCZ",
    # mechanical semi-apertures and edge data for drawings (OpticStudio 18+), optimization-wizard state
    "OEMA",
    "EDGE",
}
#: Known keywords whose meaning this reader cannot represent: always an error.
UNSUPPORTED = {
    "EFNO": "working F/# aperture (use ENPD, FNUM or FLOA)",
    "SCBD": "surface tilt/decenter",
    "TILT": "surface tilt",
    "DECX": "surface decenter",
    "DECY": "surface decenter",
    "XDAT": "extra-data surface parameters",
    "PZUP": "pickup solve",
    "ELAP": "elliptical aperture",
    "SQAP": "rectangular aperture",
    "UDAP": "user-defined aperture",
    "CLOB": "circular obscuration",
    "ELOB": "elliptical obscuration",
    "SQOB": "rectangular obscuration",
    "OBSC": "obscuration",
}
SURFACE_TYPES = ("STANDARD", "EVENASPH", "ODDASPHE")
#: What an unsupported surface type is, for the error message.
SURFACE_FEATURES = {
    "COORDBRK": "coordinate break (tilt/decenter)",
    "TOROIDAL": "toroidal/cylindrical surface",
    "BICONICX": "biconic surface",
    "BICONIC": "biconic surface",
    "DGRATING": "diffraction grating",
    "ELGRATIN": "diffraction grating",
    "BINARY_1": "binary optic (diffractive)",
    "BINARY_2": "binary optic (diffractive)",
    "BINARY_3": "binary optic (diffractive)",
    "FRESNELS": "Fresnel surface",
    "CFRESNEL": "Fresnel surface",
    "PARAXIAL": "paraxial (ideal) lens",
    "PARAX_XY": "paraxial (ideal) lens",
    "SZERNSAG": "Zernike sag surface",
    "GRINSUR1": "gradient-index surface",
    "GRADIENT": "gradient-index surface",
    "IRREGULA": "irregular (tilted/decentered) surface",
    "TILTSURF": "tilted surface",
    "USERSURF": "user-defined surface",
    "XPOLYNOM": "extended polynomial surface",
    "EXTASPHE": "extended asphere",
    "EXTODDAS": "extended odd asphere",
}
#: Our catalog folders for a Zemax GCAT name (lower-cased names not listed map to themselves).
#: MISC searches Zemax's own MISC entries (ACRYLIC with Zemax's data) before the polymers.
GCAT_TO_CATALOG = {"MISC": ("misc", "organic")}
CATALOG_TO_GCAT = {"organic": "MISC"}
#: Zemax MISC-catalog names of our polymers.
ZEMAX_POLYMER_NAMES = {"PMMA": "PMMA", "polycarbonate": "POLYCARB", "polystyrene": "POLYSTYR"}
N_EVENASPH = 8  # PARM 1..8 = a2, a4, ..., a16
N_ODDASPHE = 8  # PARM 1..8 = coefficients of r^1, r^2, ..., r^8
#: Upper bounds on counts and indices a file may give (OpticStudio's own limits are lower).
MAX_SURFACES, MAX_FIELDS, MAX_WAVES, MAX_PARM = 100_000, 1000, 1000, 1000


class ZemaxError(InputError):
    """A .zmx file (or a lens to be written as one) this module cannot map faithfully."""


@dataclass
class ZemaxImport:
    """What :func:`read_zmx` found: the prescription dict and the ignored keywords."""

    data: dict
    source: str
    ignored: list[tuple[int, str, str]] = field(default_factory=list)  # (line, keyword, why)
    notes: list[str] = field(default_factory=list)

    def ignored_summary(self) -> str:
        """One line per reason: ``why: KEY (line 3), KEY (lines 9, 17, ...)``."""
        by_why: dict[str, dict[str, list[int]]] = {}
        for line, key, why in self.ignored:
            by_why.setdefault(why, {}).setdefault(key, []).append(line)
        rows = []
        for why, keys in by_why.items():
            items = []
            for key, lines in keys.items():
                shown = ", ".join(map(str, lines[:3])) + (", ..." if len(lines) > 3 else "")
                items.append(f"{key} (line{'s' if len(lines) > 1 else ''} {shown})")
            rows.append(f"{why}: {', '.join(items)}")
        return "\n".join(rows)
