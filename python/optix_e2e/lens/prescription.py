"""Validation of the JSON lens prescription (docs/lens-format.md) and resolution of
catalog materials into the engine's resolved form.

Every error is a :class:`PrescriptionError` whose message starts with the source (file
path or ``<dict>``) and the JSON location at fault, e.g.
``lens.json: surface 4 (surfaces[3]) thickness: missing``.  Surfaces are numbered from 1
as in the engine's messages; ``surfaces[i]`` is the 0-based JSON list index.
"""

from __future__ import annotations

import copy
import math
from typing import Any

from ..errors import InputError
from . import glass as _glass

__all__ = ["PrescriptionError", "resolve_prescription"]

TOP_KEYS = {
    "name",
    "description",
    "source",
    "units",
    "aperture",
    "fields_deg",
    "wavelengths_nm",
    "wavelength_weights",
    "primary_wavelength_nm",
    "surfaces",
    "image",
    "object_distance",
}
SURFACE_KEYS = {
    "radius",
    "curvature",
    "thickness",
    "material",
    "conic",
    "aspheric",
    "semi_diameter",
    "stop",
    "name",
}
# even terms a2..a20; odd terms a1..a7 (OpticStudio's odd asphere; a1 alone is an axicon)
ASPHERIC_KEYS = {f"a{2 * i}" for i in range(1, 11)} | {"a1", "a3", "a5", "a7"}


class PrescriptionError(InputError):
    """Invalid lens prescription; the message names the source and the JSON location."""


class SurfacesCrossError(PrescriptionError):
    """Two consecutive surfaces cross inside the paraxial beam: the lens cannot exist."""


class _Checker:
    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, msg: str):
        raise PrescriptionError(f"{self.source}: {where}: {msg}")

    def number(self, where: str, value: Any, *, positive=False, nonneg=False, length=False, radius=False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(where, f"must be a number, got {_short(value)}")
        try:
            value = float(value)  # an int of hundreds of digits has no float
        except OverflowError:
            self.fail(where, f"must be finite, got a {len(str(abs(value)))}-digit number")
        if not math.isfinite(value):
            self.fail(where, f"must be finite, got {value!r}")
        if positive and value <= 0:
            self.fail(where, f"must be > 0, got {value!r}")
        if nonneg and value < 0:
            self.fail(where, f"must be >= 0, got {value!r}")
        if length and abs(value) > MAX_LENGTH_MM:
            self.fail(where, f"{value:g} mm is beyond {MAX_LENGTH_MM:g} mm")
        if radius and abs(value) > MAX_RADIUS_MM:
            self.fail(where, f'{value:g} mm is beyond {MAX_RADIUS_MM:g} mm (write "inf" for a plane)')
        return float(value)

    def numbers(self, where: str, value: Any, **kw) -> list[float]:
        if not isinstance(value, list) or not value:
            self.fail(where, f"must be a non-empty list of numbers, got {_short(value)}")
        return [self.number(f"{where}[{i}]", v, **kw) for i, v in enumerate(value)]

    def keys(self, where: str, obj: dict, allowed: set[str]):
        unknown = sorted(set(obj) - allowed)
        if unknown:
            self.fail(where, f"unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(sorted(allowed))}")


#: Largest length (mm) a thickness, semi-diameter, EPD or object distance may have, and the
#: largest radius (a huge radius is a way to write a plane): perturbing lengths near the
#: float maximum overflowed to NaN; these leave any design room.
MAX_LENGTH_MM = 1e12
MAX_RADIUS_MM = 1e30


def _short(value: Any, n: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= n else text[:n] + "..."


_SCALARS = (str, int, float, bool, type(None))


def tree_copy(x: Any) -> Any:
    """A deep copy of a JSON-like tree (dicts, lists, tuples of scalars), several times
    faster than ``copy.deepcopy`` on a prescription; anything else is deep-copied as usual."""
    if isinstance(x, _SCALARS):
        return x
    if type(x) is dict:
        return {k: tree_copy(v) for k, v in x.items()}
    if type(x) is list:
        return [tree_copy(v) for v in x]
    return copy.deepcopy(x)


def resolve_prescription(data: Any, source: str = "<dict>") -> dict:
    """Validate ``data`` and return a deep copy with every material resolved."""
    try:
        return _resolve(data, source)
    except RecursionError:
        raise PrescriptionError(f"{source}: top level: nested too deeply to be a lens prescription") from None


def _resolve(data: Any, source: str) -> dict:
    ck = _Checker(source)
    if not isinstance(data, dict):
        ck.fail("top level", f"a lens is a JSON object, got {type(data).__name__}")
    ck.keys("top level", data, TOP_KEYS)
    out = tree_copy(data)
    for key in ("name", "description", "source"):
        if not isinstance(out.get(key, ""), str):
            ck.fail(key, f"must be a string, got {_short(out[key])}")
    if out.get("units", "mm") != "mm":
        ck.fail("units", f'only "mm" is supported, got {out["units"]!r}')

    ap = out.get("aperture")
    if not isinstance(ap, dict):
        ck.fail("aperture", 'missing or not an object {"type": "epd"|"fno"|"object_na", "value": ...}')
    ck.keys("aperture", ap, {"type", "value"})
    if ap.get("type") not in ("epd", "fno", "object_na"):
        ck.fail("aperture.type", f'must be "epd", "fno" or "object_na", got {ap.get("type")!r}')
    ck.number("aperture.value", ap.get("value"), positive=True, length=True)

    # object plane to the first surface; absent, null or "inf": an object at infinity
    dist = out.get("object_distance")
    if dist is not None and not (isinstance(dist, str) and dist.casefold() in ("inf", "infinity")):
        ck.number("object_distance", dist, nonneg=True, length=True)
    finite = dist is not None and not isinstance(dist, str)
    if ap["type"] == "object_na":
        if not finite:
            ck.fail(
                "aperture.type",
                '"object_na" needs a finite "object_distance" (an object at infinity has no object-space NA)',
            )
        if ap["value"] >= 1:
            ck.fail("aperture.value", f"an object-space NA must be below 1 (object in air), got {ap['value']!r}")

    if "fields_deg" not in out:
        ck.fail("fields_deg", "missing")
    for i, f in enumerate(ck.numbers("fields_deg", out["fields_deg"], nonneg=True)):
        if f >= 90:
            ck.fail(f"fields_deg[{i}]", f"must be < 90 deg, got {f}")
    if "wavelengths_nm" not in out:
        ck.fail("wavelengths_nm", "missing")
    wls = ck.numbers("wavelengths_nm", out["wavelengths_nm"], positive=True)
    if "wavelength_weights" in out:
        w = ck.numbers("wavelength_weights", out["wavelength_weights"], nonneg=True)
        if len(w) != len(wls):
            ck.fail("wavelength_weights", f"has {len(w)} entries for {len(wls)} wavelengths")
        if sum(w) <= 0:
            ck.fail("wavelength_weights", "must not all be zero")
    if "primary_wavelength_nm" in out:
        ck.number("primary_wavelength_nm", out["primary_wavelength_nm"], positive=True)

    surfaces = out.get("surfaces")
    if not isinstance(surfaces, list) or not surfaces:
        ck.fail("surfaces", "missing or empty (a list of surface objects)")
    stops = []
    for i, s in enumerate(surfaces):
        _check_surface(ck, f"surface {i + 1} (surfaces[{i}])", s)
        if s.get("stop", False):
            stops.append(i)
    if len(stops) != 1:
        ck.fail(
            "surfaces",
            f'exactly one surface must have "stop": true, found {len(stops)}'
            + (f" (surfaces {', '.join(str(i + 1) for i in stops)})" if stops else ""),
        )

    image = out.get("image")
    if image is not None:
        if not isinstance(image, dict):
            ck.fail("image", 'must be an object {"semi_diameter": ..., "radius": ...}')
        ck.keys("image", image, {"semi_diameter", "radius"})
        if image.get("semi_diameter") is not None:
            ck.number("image.semi_diameter", image["semi_diameter"], positive=True, length=True)
        r = image.get("radius")  # a curved image surface (a curved sensor); absent or "inf": flat
        if isinstance(r, str):
            if r.strip().lower() not in ("inf", "infinity"):
                ck.fail("image.radius", f'must be a number, "inf" or null, got {_short(r)}')
            image["radius"] = "inf"
        elif r is not None and ck.number("image.radius", r, radius=True) == 0:
            ck.fail("image.radius", 'must not be 0 (use "inf" for a flat image)')
    return out


def _check_surface(ck: _Checker, where: str, s: Any):
    if not isinstance(s, dict):
        ck.fail(where, f"a surface is a JSON object, got {_short(s)}")
    ck.keys(where, s, SURFACE_KEYS)
    if "radius" in s and "curvature" in s:
        ck.fail(where, 'give "radius" or "curvature", not both')
    if "curvature" in s:
        ck.number(f"{where} curvature", s["curvature"])
    else:
        r = s.get("radius")
        if isinstance(r, str):
            if r.strip().lower() not in ("inf", "infinity"):
                ck.fail(f"{where} radius", f'must be a number, "inf" or null, got {_short(r)}')
            s["radius"] = "inf"
        elif r is not None:
            if ck.number(f"{where} radius", r, radius=True) == 0:
                ck.fail(f"{where} radius", 'must not be 0 (use "inf" for a plane)')
    if "thickness" not in s:
        ck.fail(f"{where} thickness", "missing (distance to the next surface; for the last one, to the image plane)")
    ck.number(f"{where} thickness", s["thickness"], length=True)
    if "material" not in s:
        ck.fail(f"{where} material", 'missing ("air", a glass name or a material object)')
    s["material"] = _resolve_material(ck, f"{where} material", s["material"])
    if "conic" in s:
        ck.number(f"{where} conic", s["conic"])
    if "aspheric" in s:
        a = s["aspheric"]
        if not isinstance(a, dict):
            ck.fail(f"{where} aspheric", 'must be an object like {"a4": 1e-5, "a6": ...}')
        ck.keys(f"{where} aspheric", a, ASPHERIC_KEYS)
        for k, v in a.items():
            ck.number(f"{where} aspheric.{k}", v)
    if s.get("semi_diameter") is not None:
        ck.number(f"{where} semi_diameter", s["semi_diameter"], positive=True, length=True)
    if not isinstance(s.get("stop", False), bool):
        ck.fail(f"{where} stop", f"must be true or false, got {s['stop']!r}")
    if not isinstance(s.get("name", ""), str):
        ck.fail(f"{where} name", "must be a string")


def _resolve_material(ck: _Checker, where: str, m: Any):
    if isinstance(m, str):
        if m.strip().lower() == "air":
            return "air"
        return _catalog_glass(ck, where, m, None)
    if not isinstance(m, dict):
        ck.fail(where, f'must be "air", a glass name or an object, got {_short(m)}')
    if "glass" in m:
        ck.keys(where, m, {"glass", "catalog"})
        return _catalog_glass(ck, where, m["glass"], m.get("catalog"))
    if "n" in m:
        ck.keys(where, m, {"n", "name"})
        ck.number(f"{where}.n", m["n"], positive=True)
    elif "nd" in m or "vd" in m:
        ck.keys(where, m, {"nd", "vd", "name"})
        ck.number(f"{where}.nd", m.get("nd"), positive=True)
        ck.number(f"{where}.vd", m.get("vd"), positive=True)
    elif "formula" in m:
        ck.keys(where, m, {"formula", "coefficients", "range_um", "name"})
        f = m["formula"]
        if isinstance(f, bool) or not isinstance(f, int) or not 1 <= f <= 9:
            ck.fail(f"{where}.formula", f"must be an integer 1-9 (refractiveindex.info formulas), got {_short(f)}")
        ck.numbers(f"{where}.coefficients", m.get("coefficients"))
        rng = ck.numbers(f"{where}.range_um", m.get("range_um"), positive=True)
        if len(rng) != 2 or rng[0] >= rng[1]:
            ck.fail(f"{where}.range_um", f"must be [lo, hi] with lo < hi, got {rng}")
    elif "tabulated" in m:
        ck.keys(where, m, {"tabulated", "name"})
        t = m["tabulated"]
        if not isinstance(t, list) or len(t) < 2 or not all(isinstance(r, list) and len(r) == 2 for r in t):
            ck.fail(f"{where}.tabulated", "must be a list of at least two [wl_um, n] pairs")
        for i, r in enumerate(t):
            ck.number(f"{where}.tabulated[{i}][0]", r[0], positive=True)
            ck.number(f"{where}.tabulated[{i}][1]", r[1], positive=True)
    else:
        ck.fail(where, f"unknown material form {_short(m)}; see docs/lens-format.md")
    return m


def _catalog_glass(ck: _Checker, where: str, name: Any, catalog: Any):
    if not isinstance(name, str) or not name.strip():
        ck.fail(f"{where}.glass", f"must be a glass name (a string), got {_short(name)}")
    if catalog is not None and not isinstance(catalog, str):
        ck.fail(f"{where}.catalog", f"must be a catalog name (a string), got {_short(catalog)}")
    try:
        return _glass.resolve(name, catalog).to_engine()
    except _glass.GlassError as exc:
        ck.fail(where, str(exc))
