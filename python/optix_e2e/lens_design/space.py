"""Parameter spaces over a base lens: named, bounded design variables.

A parameter is ``{name, kind, surface, min, max, unit}``.  ``surface`` is 1-based as in the
prescription's error messages (and in the paper's Table 1, where the stop is a surface of
its own).  Kinds and what they change on ``surfaces[surface - 1]``:

* ``radius``                   radius of curvature (mm)
* ``conic``                    conic constant k
* ``asphere_2nd`` ... ``asphere_20th``  even-asphere coefficient a2 ... a20 (mm^(1-n))
* ``thickness`` / ``air_gap``  axial distance to the next surface (mm); ``thickness`` is
  used when the medium after the surface is a material, ``air_gap`` when it is air.
* ``f_number`` / ``epd``       the aperture (whole system; ``surface`` is 0): the lens's
  aperture becomes ``{"type": "fno" | "epd", "value": v}``.

Names follow the paper's Table 1 (``s_1_radius``, ``s_1_conic``, ``s_1_4th`` ... ``s_1_10th``)
plus ``s_N_thickness`` for the distance after surface N, ``f_number`` and ``epd``.  A space
file may give any name (e.g. Table 1's ``l_12``) as long as kind and surface say what it
changes.

Space files are TOML (``lens = "paper-triplet"`` naming the base lens, then one
``[[parameter]]`` table per parameter; docs/spaces.md) or JSON (a list of parameter objects,
or ``{"lens": ..., "parameters": [...]}``).  :func:`load_space` resolves a path or a bundled
lens's name to its space and base lens.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

from ..errors import InputError
from ..io import write_text_atomic

__all__ = [
    "Parameter",
    "ParameterSpace",
    "SpaceError",
    "parameter_from_name",
    "default_bounds",
    "load_space",
    "bundled_spaces",
]

ORDINAL = {
    2: "2nd",
    4: "4th",
    6: "6th",
    8: "8th",
    10: "10th",
    12: "12th",
    14: "14th",
    16: "16th",
    18: "18th",
    20: "20th",
}
ASPHERE_KINDS = {f"asphere_{v}": k for k, v in ORDINAL.items()}
APERTURE_KINDS = {"f_number": "fno", "epd": "epd"}
KINDS = {"radius", "conic", "thickness", "air_gap", *ASPHERE_KINDS, *APERTURE_KINDS}
UNITS = {
    "radius": "mm",
    "conic": "-",
    "thickness": "mm",
    "air_gap": "mm",
    "f_number": "-",
    "epd": "mm",
    **{f"asphere_{v}": f"mm^-{k - 1}" for k, v in ORDINAL.items()},
}
_NAME = re.compile(r"^s_(\d+)_(radius|conic|thickness|(\d+)(?:st|nd|rd|th))$")


class SpaceError(InputError):
    """Invalid parameter space or parameter name; the message names the file and entry."""


@dataclass(frozen=True)
class Parameter:
    name: str
    kind: str
    surface: int  # 1-based; 0 for the aperture kinds
    min: float
    max: float
    unit: str = ""

    def get(self, lens: dict) -> float:
        """Current value of this parameter in a lens dict."""
        if self.kind in APERTURE_KINDS:
            ap = lens["aperture"]
            if ap["type"] != APERTURE_KINDS[self.kind]:
                raise SpaceError(
                    f"parameter {self.name!r} ({self.kind}): the lens's aperture is "
                    f"given as {ap['type']!r}, not {APERTURE_KINDS[self.kind]!r}"
                )
            return float(ap["value"])
        s = lens["surfaces"][self.surface - 1]
        if self.kind == "radius":
            if "curvature" in s:
                return math.inf if s["curvature"] == 0 else 1.0 / s["curvature"]
            r = s.get("radius")
            return math.inf if r in (None, "inf") else float(r)
        if self.kind == "conic":
            return float(s.get("conic", 0.0))
        if self.kind in ("thickness", "air_gap"):
            return float(s["thickness"])
        return float((s.get("aspheric") or {}).get(f"a{ASPHERE_KINDS[self.kind]}", 0.0))

    def set(self, lens: dict, value: float) -> None:
        """Write ``value`` into a lens dict (in place)."""
        value = float(value)
        if self.kind in APERTURE_KINDS:
            lens["aperture"] = {"type": APERTURE_KINDS[self.kind], "value": value}
            return
        s = lens["surfaces"][self.surface - 1]
        if self.kind == "radius":
            s.pop("curvature", None)
            s["radius"] = value
        elif self.kind == "conic":
            s["conic"] = value
        elif self.kind in ("thickness", "air_gap"):
            s["thickness"] = value
        else:
            asph = dict(s.get("aspheric") or {})
            asph[f"a{ASPHERE_KINDS[self.kind]}"] = value
            s["aspheric"] = asph


def _is_air(material) -> bool:
    return material == "air" or (isinstance(material, str) and material.lower() == "air")


def parameter_from_name(
    name: str, lens: dict, bounds: tuple[float, float] | None = None, semi_diameters: Sequence[float] | None = None
) -> Parameter:
    """A parameter from a Table-1 style name (``s_3_radius``, ``s_1_4th``, ``s_2_thickness``),
    with ``bounds`` or :func:`default_bounds` around the lens's current value."""
    if name.strip() in APERTURE_KINDS:
        kind = name.strip()
        p = Parameter(kind, kind, 0, -math.inf, math.inf, UNITS[kind])
        p.get(lens)  # the lens's aperture must be of this kind
        lo, hi = bounds if bounds is not None else default_bounds(p, lens, semi_diameters)
        return Parameter(kind, kind, 0, float(lo), float(hi), UNITS[kind])
    m = _NAME.match(name.strip())
    if not m:
        raise SpaceError(
            f"parameter {name!r}: expected s_N_radius, s_N_conic, s_N_thickness, "
            f"s_N_<order> with order 2nd, 4th, ..., 20th (e.g. s_1_4th), f_number or epd"
        )
    surf = int(m.group(1))
    n = len(lens["surfaces"])
    if not 1 <= surf <= n:
        raise SpaceError(f"parameter {name!r}: surface {surf} out of range (lens has surfaces 1..{n})")
    if m.group(3):
        order = int(m.group(3))
        if order not in ORDINAL or ORDINAL[order] != m.group(2):
            raise SpaceError(f"parameter {name!r}: asphere order must be one of {', '.join(ORDINAL.values())}")
        kind = f"asphere_{ORDINAL[order]}"
    elif m.group(2) == "thickness":
        kind = "air_gap" if _is_air(lens["surfaces"][surf - 1]["material"]) else "thickness"
    else:
        kind = m.group(2)
    p = Parameter(name, kind, surf, -math.inf, math.inf, UNITS[kind])
    lo, hi = bounds if bounds is not None else default_bounds(p, lens, semi_diameters)
    return Parameter(name, kind, surf, float(lo), float(hi), UNITS[kind])


def default_bounds(p: Parameter, lens: dict, semi_diameters: Sequence[float] | None = None) -> tuple[float, float]:
    """Bounds used when a variable is chosen by name only (no space file).

    Radii keep their sign within 0.5x..3x of the current value (a flat surface needs a
    space file); conics +-2 around the current value; f-number and EPD 0.8x..1.25x; thicknesses 0.3x..3x + 1 mm (air gaps
    may close to 0); asphere coefficients +- the value that makes 0.5 mm of sag at the
    surface's semi-diameter (``semi_diameters`` (e.g. the ray footprint), else the
    prescription's, else 10 mm).
    """
    v = p.get(lens)
    if p.kind == "radius":
        if not math.isfinite(v):
            raise SpaceError(f"parameter {p.name!r}: surface {p.surface} is flat; give bounds in a space file")
        a, b = 0.5 * v, 3.0 * v
        return (min(a, b), max(a, b))
    if p.kind == "conic":
        return (v - 2.0, v + 2.0)
    if p.kind in APERTURE_KINDS:
        return (0.8 * v, 1.25 * v)
    if p.kind == "thickness":
        return (0.3 * v, 3.0 * v + 1.0)
    if p.kind == "air_gap":
        return (0.0, 3.0 * v + 1.0)
    order = ASPHERE_KINDS[p.kind]
    h = (
        semi_diameters[p.surface - 1]
        if semi_diameters is not None
        else lens["surfaces"][p.surface - 1].get("semi_diameter")
    ) or 10.0
    amp = 0.5 / h**order
    return (v - amp, v + amp)


@dataclass
class Limits:
    """Manufacturability limits (mm); ``None`` = not checked."""

    min_center: float | None = None
    min_edge: float | None = None
    min_air_gap: float | None = None
    min_bfd: float | None = None

    @classmethod
    def from_dict(cls, d: dict | None, source: str = "constraints") -> "Limits":
        d = dict(d or {})
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise SpaceError(
                f"{source}: unknown constraint(s) {', '.join(unknown)} (known: {', '.join(cls.__dataclass_fields__)})"
            )
        for k, v in d.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise SpaceError(f"{source}: {k} must be a finite number >= 0, got {v!r}")
        return cls(**{k: float(v) for k, v in d.items()})

    def merged(self, **override) -> "Limits":
        return Limits(**{**asdict(self), **{k: v for k, v in override.items() if v is not None}})


class ParameterSpace:
    """An ordered list of :class:`Parameter` over a base lens."""

    def __init__(
        self,
        params: Sequence[Parameter],
        source: str = "<space>",
        lens_ref: str | None = None,
        description: str | None = None,
        notes: dict[str, str] | None = None,
        constraints: dict | None = None,
    ):
        self.params = list(params)
        self.source = source
        self.lens_ref = lens_ref  # base lens named by the file (bundled name or path)
        self.description = description
        self.notes = dict(notes or {})  # parameter name -> note
        self.constraints = dict(constraints or {})  # manufacturability limits (optix_e2e.lens_design.sampling)
        names = [p.name for p in self.params]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise SpaceError(f"{source}: duplicate parameter name(s) {', '.join(dup)}")
        targets = [(p.surface, p.kind) for p in self.params]
        clash = sorted({t for t in targets if targets.count(t) > 1})
        if clash:
            raise SpaceError(
                f"{source}: several parameters change the same thing: "
                + ", ".join(f"surface {s} {k}" for s, k in clash)
            )

    def with_ranges(
        self,
        ranges: Sequence[tuple[float, float]],
        source: str,
        lens_ref: str | None = None,
        description: str | None = None,
    ) -> "ParameterSpace":
        """The same parameters, notes and limits over new (min, max) ranges, each end rounded
        to 6 significant digits (what a space file keeps): how the space scripts make a space
        from another (scripts/recentre_space.py, scripts/paper_width_space.py)."""
        if len(ranges) != len(self.params):
            raise SpaceError(f"{source}: {len(ranges)} ranges for {len(self.params)} parameters")
        params = []
        for p, (lo, hi) in zip(self.params, ranges):
            lo, hi = float(f"{lo:.6g}"), float(f"{hi:.6g}")
            params.append(Parameter(p.name, p.kind, p.surface, min(lo, hi), max(lo, hi), p.unit))
        return ParameterSpace(
            params,
            source=source,
            lens_ref=lens_ref or self.lens_ref,
            description=description or self.description,
            notes=self.notes,
            constraints=self.constraints,
        )

    # ----- construction ---------------------------------------------------------------
    @classmethod
    def from_names(
        cls, names: "str | Sequence[str]", lens: dict, semi_diameters: Sequence[float] | None = None
    ) -> "ParameterSpace":
        if isinstance(names, str):
            names = [n for n in (x.strip() for x in names.split(",")) if n]
        if not names:
            raise SpaceError("no variables given")
        return cls([parameter_from_name(n, lens, semi_diameters=semi_diameters) for n in names], source="--vars")

    @classmethod
    def load(cls, path: "str | Path", lens: dict | None = None) -> "ParameterSpace":
        """Read a space file: TOML (``lens = ...`` and ``[[parameter]]`` tables) or JSON (a
        list of parameter objects, or ``{"lens": ..., "parameters": [...]}``).  ``lens``
        (a lens dict) checks the surface numbers; the file's own ``lens`` entry is kept as
        :attr:`lens_ref`."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise SpaceError(f"{path}: cannot read space file ({exc.strerror or exc})") from exc
        except UnicodeDecodeError as exc:
            raise SpaceError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
        if path.suffix.lower() == ".toml":
            try:
                data = _toml().loads(text)
            except _toml().TOMLDecodeError as exc:
                raise SpaceError(f"{path}: invalid TOML: {exc}") from exc
            except RecursionError:
                raise SpaceError(f"{path}: invalid TOML: nested too deeply to be a parameter space") from None
            key = "parameter"
        else:
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                raise SpaceError(f"{path}:{exc.lineno}:{exc.colno}: invalid JSON: {exc.msg}") from exc
            except RecursionError:
                raise SpaceError(f"{path}: invalid JSON: nested too deeply to be a parameter space") from None
            key = "parameters"
        lens_ref = None
        if isinstance(data, dict):
            unknown = sorted(set(data) - {"lens", "source", "description", "constraints", key})
            if unknown:
                raise SpaceError(
                    f"{path}: unknown top-level key(s) {', '.join(unknown)} "
                    f"(expected lens, source, description, constraints, {key})"
                )
            constraints = data.get("constraints")
            if constraints is not None and not isinstance(constraints, dict):
                raise SpaceError(f"{path}: constraints must be a table (min_air_gap = 1.0, ...)")
            Limits.from_dict(constraints, f"{path}: [constraints]")  # a misspelt or bad limit: refused here
            lens_ref = data.get("lens")
            if lens_ref is not None and not isinstance(lens_ref, str):
                raise SpaceError(f"{path}: lens must be a bundled lens name or a path, got {lens_ref!r}")
            description = data.get("description") or data.get("source")
            data = data.get(key)
        else:
            description = constraints = None
        if not isinstance(data, list) or not data:
            raise SpaceError(
                f"{path}: no parameters (a TOML space has [[parameter]] tables; a JSON "
                f'space is a list of parameters or an object with a "parameters" list)'
            )
        label = "[[parameter]] #{}" if key == "parameter" else "parameters[{}]"
        params = [
            cls._entry(path, label.format(i + 1 if key == "parameter" else i), e, lens) for i, e in enumerate(data)
        ]
        notes = {e["name"]: e["note"] for e in data if "note" in e}
        return cls(
            params, source=str(path), lens_ref=lens_ref, description=description, notes=notes, constraints=constraints
        )

    def base_lens(self):
        """The base lens the file names (``lens``): a bundled name, or a path relative to
        the space file."""
        from ..lens import Lens, LensLoadError

        ref = self.lens_ref
        if not ref:
            raise SpaceError(f'{self.source}: the space names no base lens (add lens = "...")')
        candidate = Path(self.source).parent / ref
        try:
            lens = Lens.load(str(candidate) if candidate.is_file() else ref)
        except LensLoadError as exc:
            raise SpaceError(f"{self.source}: base lens {ref!r}: {exc}") from exc
        bad = [p.name for p in self.params if p.surface > len(lens.surfaces)]
        if bad:
            raise SpaceError(
                f"{self.source}: parameter(s) {', '.join(bad)} name a surface beyond the "
                f"base lens's {len(lens.surfaces)} surfaces"
            )
        return lens

    def save_toml(self, path: "str | Path", lens_ref: str | None = None, description: str | None = None) -> None:
        """Write the space as TOML (what :meth:`load` reads back)."""
        import tomli_w

        doc: dict = {}
        ref = lens_ref or self.lens_ref
        if ref:
            doc["lens"] = ref
        desc = description or self.description
        if desc:
            doc["description"] = desc
        if self.constraints:
            doc["constraints"] = self.constraints
        doc["parameter"] = [
            {**asdict(p), **({"note": self.notes[p.name]} if p.name in self.notes else {})} for p in self.params
        ]
        write_text_atomic(path, tomli_w.dumps(doc))

    @staticmethod
    def _entry(path, entry: str, e, lens) -> Parameter:
        where = f"{path}: {entry}"
        if not isinstance(e, dict):
            raise SpaceError(f"{where}: must be an object with name, kind, surface, min, max, unit")
        unknown = sorted(set(e) - {"name", "kind", "surface", "min", "max", "unit", "note"})
        if unknown:
            raise SpaceError(f"{where}: unknown key(s) {', '.join(unknown)}")
        for key in ("name", "kind", "surface", "min", "max"):
            if key not in e:
                raise SpaceError(f"{where}: missing {key!r}")
        name = e["name"]
        if not isinstance(name, str) or not name:
            raise SpaceError(f"{where}: name must be a text, got {name!r}")
        where = f"{path}: {entry} ({name})"
        if not isinstance(e["kind"], str) or e["kind"] not in KINDS:
            raise SpaceError(f"{where}: kind {e['kind']!r} is not one of {', '.join(sorted(KINDS))}")
        surf = e["surface"]
        if e["kind"] in APERTURE_KINDS:
            if surf != 0:
                raise SpaceError(f"{where}: an aperture parameter ({e['kind']}) has surface = 0, got {surf!r}")
        elif isinstance(surf, bool) or not isinstance(surf, int) or surf < 1:
            raise SpaceError(f"{where}: surface must be an integer >= 1, got {surf!r}")
        lo, hi = e["min"], e["max"]
        for key, v in (("min", lo), ("max", hi)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise SpaceError(f"{where}: {key} must be a finite number, got {v!r}")
        if not lo < hi:
            raise SpaceError(f"{where}: min {lo} must be < max {hi}")
        if e["kind"] == "radius" and lo < 0 < hi:
            raise SpaceError(f"{where}: a radius range may not contain 0 ({lo}..{hi})")
        if e["kind"] in ("thickness", "f_number", "epd") and lo <= 0:
            raise SpaceError(f"{where}: {e['kind']} must stay positive (min {lo})")
        if e["kind"] == "air_gap" and lo < 0:
            raise SpaceError(f"{where}: an air gap may not be negative (min {lo})")
        unit = e.get("unit", UNITS[e["kind"]])
        if unit != UNITS[e["kind"]]:
            raise SpaceError(f"{where}: unit {unit!r} for kind {e['kind']}; expected {UNITS[e['kind']]!r}")
        if lens is not None:
            n = len(lens["surfaces"])
            if surf > n:
                raise SpaceError(f"{where}: surface {surf} out of range (lens has surfaces 1..{n})")
        return Parameter(name, e["kind"], surf, float(lo), float(hi), unit)

    def to_json(self) -> list[dict]:
        return [asdict(p) for p in self.params]

    # ----- use ------------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return [p.name for p in self.params]

    def __len__(self) -> int:
        return len(self.params)

    def values(self, lens: dict) -> list[float]:
        return [p.get(lens) for p in self.params]

    def apply(self, lens: dict, values: Sequence[float]) -> dict:
        """A new lens dict with ``values`` written in (the input is not modified).  Its
        surface dicts (with their aspheric terms) and aperture are its own; materials and the
        field and wavelength lists are shared with ``lens`` (nothing here changes them), which
        keeps this cheap for the dataset generator's thousands of designs."""
        if len(values) != len(self.params):
            raise SpaceError(f"{self.source}: {len(values)} values for {len(self.params)} parameters")
        out = dict(lens)
        out["surfaces"] = [
            dict(sf, aspheric=dict(sf["aspheric"])) if sf.get("aspheric") else dict(sf) for sf in lens["surfaces"]
        ]
        if "aperture" in out:
            out["aperture"] = dict(out["aperture"])
        for p, v in zip(self.params, values):
            if not math.isfinite(float(v)):
                raise SpaceError(f"{self.source}: parameter {p.name}: value {v!r} is not finite")
            p.set(out, v)
        return out

    def check_bounds(self, lens: dict, tol: float = 1e-12) -> list[str]:
        """Messages for each parameter whose value in ``lens`` lies outside its range."""
        out = []
        for p in self.params:
            v = p.get(lens)
            span = tol * max(1.0, abs(p.max - p.min))
            if not (p.min - span <= v <= p.max + span):
                out.append(f"{p.name} = {v:.6g} outside [{p.min:.6g}, {p.max:.6g}] {p.unit}")
        return out


def _toml():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    return tomllib


SPACES_DIR = Path(__file__).resolve().parent.parent / "bundled" / "spaces"


def bundled_spaces() -> list[str]:
    """Names of the bundled lenses that ship a parameter space."""
    return sorted(p.stem for p in SPACES_DIR.glob("*.toml"))


def load_space(spec: "str | Path") -> tuple[ParameterSpace, "object"]:
    """(space, base Lens) from a space file path or a bundled lens's name."""
    path = Path(spec)
    if not path.is_file():
        bundled = SPACES_DIR / f"{spec}.toml"
        if bundled.is_file():
            path = bundled
        else:
            raise SpaceError(
                f"{spec!r} is neither a space file nor a bundled lens with a space "
                f"(bundled: {', '.join(bundled_spaces())})"
            )
    space = ParameterSpace.load(path)
    lens = space.base_lens()
    bad = space.check_bounds(lens.data)
    if bad:
        raise SpaceError(f"{path}: the base lens lies outside the space: " + "; ".join(bad))
    return space, lens
