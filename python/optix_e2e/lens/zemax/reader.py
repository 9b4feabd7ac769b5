"""Reading .zmx files into our JSON prescription (docs/zemax.md)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ... import engine
from .. import glass as _glass
from ..text import display_name
from .common import (
    GCAT_TO_CATALOG,
    IGNORED,
    MAX_FIELDS,
    MAX_PARM,
    MAX_SURFACES,
    MAX_WAVES,
    N_EVENASPH,
    N_ODDASPHE,
    SURFACE_FEATURES,
    SURFACE_TYPES,
    UNITS_MM,
    UNSUPPORTED,
    ZemaxError,
    ZemaxImport,
)
from .glass_names import successor_names
from .numbers import _from_um, _radius


def _decode(raw: bytes, source: str) -> tuple[str, str]:
    """Text and the encoding used. OpticStudio writes UTF-16 LE with a BOM."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        enc = "utf-16"
    elif raw.startswith(b"\xef\xbb\xbf"):
        enc = "utf-8-sig"
    elif len(raw) > 1 and raw[1:2] == b"\x00":
        enc = "utf-16-le"
    else:
        enc = "utf-8"
    try:
        return raw.decode(enc), enc
    except UnicodeDecodeError as exc:
        if enc.startswith("utf-16"):
            raise ZemaxError(
                f"{source}: cannot decode as {enc} at byte {exc.start} ({exc.reason}; truncated file?)"
            ) from None
        return raw.decode("latin-1"), "latin-1"  # older ANSI files


def read_zmx(path: "str | Path", *, strict: bool = True) -> ZemaxImport:
    """Read a sequential .zmx file (UTF-8 or UTF-16). ``strict=False`` lists unknown
    keywords as ignored instead of failing (known-unsupported ones still fail)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ZemaxError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    text, enc = _decode(raw, str(path))
    imp = parse_zmx(text, source=str(path), strict=strict, name=display_name(path.stem))
    imp.notes.insert(0, f"encoding {enc}")
    return imp


class _Parser:
    def __init__(self, source: str, strict: bool):
        self.source, self.strict = source, strict
        self.ignored: list[tuple[int, str, str]] = []
        self.notes: list[str] = []
        self.hdr: dict[str, Any] = {}
        self.surfs: list[dict[str, Any]] = []
        self.wavm: dict[int, tuple[float, float, int]] = {}

    def fail(self, line: int, key: str, msg: str):
        raise ZemaxError(f"{self.source}:{line}: {key}: {msg}")

    def num(self, line: int, key: str, tok: list[str], i: int, default=None) -> float:
        if i >= len(tok):
            if default is not None:
                return default
            self.fail(line, key, f"value {i} missing (truncated line?)")
        try:
            v = float(tok[i].replace(",", "."))  # some locales write decimal commas
        except ValueError:
            self.fail(line, key, f"expected a number, got {tok[i]!r}")
        if not math.isfinite(v):
            self.fail(line, key, f"expected a finite number, got {tok[i]!r}")
        return v

    def int_(
        self,
        line: int,
        key: str,
        tok: list[str],
        i: int,
        default: int | None = None,
        lo: int | None = None,
        hi: int | None = None,
        what: str = "value",
    ) -> int:
        """An integer token; a fraction ('2.5', '1,5') or a value outside lo..hi is an error."""
        if i >= len(tok) and default is not None:
            return default
        v = self.num(line, key, tok, i)
        if not v.is_integer():
            self.fail(line, key, f"{what} must be an integer, got {tok[i]!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            self.fail(line, key, f"{what} {tok[i]} outside {lo}..{hi}")
        return int(v)

    def nums(self, line, key, tok):
        return [self.num(line, key, tok, i) for i in range(1, len(tok))]

    def where(self, s) -> str:
        return f"SURF {s['id']}"

    def feed(self, lineno: int, raw_line: str):
        tok = raw_line.split()
        if not tok:
            return
        key = tok[0]
        rest = raw_line.strip()[len(key) :].strip()
        if key == "SURF":
            sid = self.int_(lineno, key, tok, 1, lo=0, hi=MAX_SURFACES, what="surface number")
            if sid != len(self.surfs):
                self.fail(lineno, key, f"surface {sid} out of order (expected SURF {len(self.surfs)})")
            self.surfs.append(
                {"id": sid, "line": lineno, "type": "STANDARD", "curv": 0.0, "disz": 0.0, "parm": {}, "lines": {}}
            )
            return
        s = self.surfs[-1] if self.surfs else None
        if key in UNSUPPORTED:
            self.fail(lineno, key, f"{UNSUPPORTED[key]} is not supported")
        if key in IGNORED:
            self._ignore(lineno, key, tok, s)
            return
        handler = getattr(self, f"k_{key}", None)
        if handler is not None and key in HEADER_KEYS:
            handler(lineno, key, tok, rest, None)  # file-level: allowed anywhere
            return
        if handler is not None and s is None:
            self.fail(lineno, key, "surface keyword before the first SURF")
        if handler is None:
            if self.strict:
                self.fail(
                    lineno,
                    key,
                    "unknown keyword; not supported by this reader "
                    "(see docs/zemax.md; strict=False / --lenient lists it as ignored)",
                )
            self.ignored.append((lineno, key, "unknown keyword (lenient mode)"))
            return
        s["lines"][key] = lineno
        handler(lineno, key, tok, rest, s)

    def _ignore(self, line, key, tok, s):
        why = "display/bookkeeping only"
        if key in ("VDXN", "VDYN", "VCXN", "VCYN", "VANN"):
            if any(v != 0 for v in self.nums(line, key, tok)):
                why = "Zemax vignetting factors; optix vignettes by clipping at the semi-diameters instead"
            else:
                return  # all zero: nothing to report
        elif key in ("FWGN", "FWGT"):
            why = "field weights (used by Zemax's merit function only)"
        elif key == "RAIM":
            why = 'ray-aiming setting (optix picks aiming per analysis: aiming="paraxial"|"real")'
        elif key == "COAT":
            why = "coating (transmission only; optix traces uncoated geometry)"
        self.ignored.append((line, key, why))

    # header keywords ------------------------------------------------------------
    def k_MODE(self, line, key, tok, rest, s):
        if tok[1:2] != ["SEQ"]:
            self.fail(line, key, f"only sequential files are supported (MODE SEQ), got {rest!r}")

    def k_NAME(self, line, key, tok, rest, s):
        self.hdr["name"] = rest.strip('"')

    def k_UNIT(self, line, key, tok, rest, s):
        u = tok[1].upper() if len(tok) > 1 else ""
        if u not in UNITS_MM:
            self.fail(line, key, f"unknown lens unit {u!r} (MM, CM, IN or METER)")
        self.hdr["unit"] = u

    def _aperture(self, line, key, ap):
        if "aperture" in self.hdr:
            self.fail(
                line,
                key,
                f"second aperture definition (first: {self.hdr['aperture_key']} on line {self.hdr['aperture_line']})",
            )
        self.hdr.update(aperture=ap, aperture_key=key, aperture_line=line)

    def k_ENPD(self, line, key, tok, rest, s):
        v = self.num(line, key, tok, 1)
        if v < 0:
            self.fail(line, key, f"entrance pupil diameter must be >= 0, got {v}")
        if v == 0:  # no pupil given: the stop's aperture sets it, as for FLOA
            self.notes.append(f"line {line}: ENPD 0, the stop's clear aperture sets the pupil (as FLOA)")
            self._aperture(line, key, ("floa", None))
        else:
            self._aperture(line, key, ("epd", v))

    def k_FNUM(self, line, key, tok, rest, s):
        v = self.num(line, key, tok, 1)
        flag = self.int_(line, key, tok, 2, default=0, what="F/# type flag")
        if flag != 0:
            self.fail(line, key, f"FNUM type flag {flag} (only 0, image-space F/# = EFL/EPD, is supported)")
        if v <= 0:
            self.fail(line, key, f"F-number must be > 0, got {v}")
        self._aperture(line, key, ("fno", v))

    def k_FLOA(self, line, key, tok, rest, s):
        self._aperture(line, key, ("floa", None))

    def k_OBNA(self, line, key, tok, rest, s):
        # OBNA na flag: object-space numerical aperture (a finite object only, checked in _build)
        v = self.num(line, key, tok, 1)
        if not 0 < v < 1:
            self.fail(line, key, f"object-space NA must lie in (0, 1) (object in air), got {v:g}")
        self._aperture(line, key, ("object_na", v))

    def k_ENVD(self, line, key, tok, rest, s):
        t, p = self.num(line, key, tok, 1, 20.0), self.num(line, key, tok, 2, 1.0)
        if t != 20 or p != 1:
            self.fail(
                line,
                key,
                f"environment {t:g} C, {p:g} atm: thermal/pressure index changes are not modelled (20 C, 1 atm only)",
            )
        self.ignored.append((line, key, "standard environment 20 C, 1 atm"))

    def k_GCAT(self, line, key, tok, rest, s):
        self.hdr["gcat"] = tok[1:]

    def k_FTYP(self, line, key, tok, rest, s):
        # FTYP type telecentric n_fields n_waves normalization ? ? n_fields (OpticStudio 18+
        # repeats the field count as the 8th number; older files stop earlier).
        ftype = self.int_(line, key, tok, 1, 0, what="field type")
        self.hdr["ftype"] = (line, ftype)  # checked with the field values in _fields
        if self.int_(line, key, tok, 2, 0, what="telecentric flag") != 0:
            self.fail(line, key, "object-space telecentric systems are not supported")
        if len(tok) > 4:
            self.hdr["n_fields"] = self.int_(line, key, tok, 3, lo=1, hi=MAX_FIELDS, what="field count")
            self.hdr["n_waves"] = self.int_(line, key, tok, 4, lo=1, hi=MAX_WAVES, what="wavelength count")
        for i in range(5, min(len(tok), 9)):
            self.int_(line, key, tok, i, what=f"FTYP value {i}")

    def k_XFLN(self, line, key, tok, rest, s):
        self.hdr["xfld"] = (line, key, self.nums(line, key, tok))

    def k_YFLN(self, line, key, tok, rest, s):
        self.hdr["yfld"] = (line, key, self.nums(line, key, tok))

    k_XFLD, k_YFLD = k_XFLN, k_YFLN  # older files

    def k_WAVM(self, line, key, tok, rest, s):
        slot = self.int_(line, key, tok, 1, lo=1, hi=MAX_WAVES, what="wavelength slot")
        self.wavm[slot] = (self.num(line, key, tok, 2), self.num(line, key, tok, 3, 1.0), line)

    def k_WAVL(self, line, key, tok, rest, s):  # older files: all wavelengths on one line
        if len(tok) - 1 > MAX_WAVES:
            self.fail(line, key, f"{len(tok) - 1} wavelengths (at most {MAX_WAVES})")
        for i, w in enumerate(self.nums(line, key, tok), 1):
            old = self.wavm.get(i, (0, 1.0, line))
            self.wavm[i] = (w, old[1], line)

    def k_WWGT(self, line, key, tok, rest, s):
        for i, w in enumerate(self.nums(line, key, tok), 1):
            old = self.wavm.get(i, (0.55, 1.0, line))
            self.wavm[i] = (old[0], w, old[2])

    def k_PWAV(self, line, key, tok, rest, s):
        self.hdr["pwav"] = (line, self.int_(line, key, tok, 1, lo=1, hi=MAX_WAVES, what="primary wavelength"))

    def k_MNUM(self, line, key, tok, rest, s):
        if self.int_(line, key, tok, 1, what="configuration count") > 1:
            self.fail(line, key, "multi-configuration files are not supported")

    # surface keywords -----------------------------------------------------------
    def k_TYPE(self, line, key, tok, rest, s):
        t = tok[1] if len(tok) > 1 else ""
        if t not in SURFACE_TYPES:
            what = f"{SURFACE_FEATURES[t]} ({t})" if t in SURFACE_FEATURES else f"unknown surface type {t!r}"
            self.fail(line, key, f"{self.where(s)}: {what} is not supported; supported: {', '.join(SURFACE_TYPES)}")
        s["type"] = t

    def k_CURV(self, line, key, tok, rest, s):
        c = self.num(line, key, tok, 1)
        if c != 0 and not math.isfinite(1.0 / c):
            self.fail(
                line, key, f"{self.where(s)}: curvature {tok[1]} has no finite radius (write 0 for a flat surface)"
            )
        s["curv"] = c

    def k_DISZ(self, line, key, tok, rest, s):
        s["disz"] = math.inf if tok[1:2] == ["INFINITY"] else self.num(line, key, tok, 1)

    def k_CONI(self, line, key, tok, rest, s):
        s["coni"] = self.num(line, key, tok, 1)

    def k_PARM(self, line, key, tok, rest, s):
        i = self.int_(line, key, tok, 1, lo=0, hi=MAX_PARM, what="parameter number")
        s["parm"][i] = (self.num(line, key, tok, 2), line)

    def k_PPAR(self, line, key, tok, rest, s):
        # PPAR n surface scale offset [column]: parameter n is a pickup solve, scale x the
        # other surface's parameter + offset. OpticStudio writes the solved value on the
        # PARM line as well; that value is imported and the pickup checked against it.
        n = self.int_(line, key, tok, 1, lo=0, hi=MAX_PARM, what="parameter number")
        src = self.int_(line, key, tok, 2, lo=-MAX_SURFACES, hi=MAX_SURFACES, what="pickup surface")
        scale, offset = self.num(line, key, tok, 3, 1.0), self.num(line, key, tok, 4, 0.0)
        column = self.int_(line, key, tok, 5, 0, lo=0, hi=MAX_PARM, what="pickup column")
        s.setdefault("ppar", {})[n] = (line, src, scale, offset, column)

    def k_PKUP(self, line, key, tok, rest, s):
        # PKUP surface scale offset: the conic is a pickup solve; OpticStudio writes the
        # solved value on the CONI line, which is what is imported.
        self.int_(line, key, tok, 1, lo=-MAX_SURFACES, hi=MAX_SURFACES, what="pickup surface")
        self.num(line, key, tok, 2, 1.0), self.num(line, key, tok, 3, 0.0)
        self.ignored.append((line, key, "conic pickup solve (the CONI value written with it is imported)"))

    def k_STOP(self, line, key, tok, rest, s):
        s["stop"] = True

    def k_COMM(self, line, key, tok, rest, s):
        s["comm"] = rest.strip('"')

    def k_DIAM(self, line, key, tok, rest, s):
        s["diam"] = (self.num(line, key, tok, 1), self.int_(line, key, tok, 2, 0, what="DIAM solve flag"))

    def k_CLAP(self, line, key, tok, rest, s):
        rmin, rmax = self.num(line, key, tok, 1), self.num(line, key, tok, 2)
        if rmin != 0:
            self.fail(line, key, f"{self.where(s)}: annular aperture (r_min {rmin:g}) is not supported")
        s["clap"] = rmax

    def k_IGNR(self, line, key, tok, rest, s):
        if self.int_(line, key, tok, 1, 0, what="IGNR flag") != 0:
            self.fail(line, key, f"{self.where(s)} is marked 'ignore this surface', which is not supported")

    def k_FLAP(self, line, key, tok, rest, s):
        # FLAP solve sd ...: a floating aperture at sd (OpticStudio writes the DIAM value).
        s["flap"] = self.num(line, key, tok, 2, default=0.0)

    def k_OBDC(self, line, key, tok, rest, s):
        if any(v != 0 for v in self.nums(line, key, tok)):
            self.fail(line, key, f"{self.where(s)}: decentered aperture is not supported")

    def k_GLAS(self, line, key, tok, rest, s):
        if len(tok) < 2:
            self.fail(line, key, f"{self.where(s)}: glass name missing (truncated line?)")
        s["glas"] = (line, tok)


HEADER_KEYS = {
    "MODE",
    "NAME",
    "UNIT",
    "ENPD",
    "FNUM",
    "FLOA",
    "OBNA",
    "ENVD",
    "GCAT",
    "FTYP",
    "XFLN",
    "YFLN",
    "XFLD",
    "YFLD",
    "WAVM",
    "WAVL",
    "WWGT",
    "PWAV",
    "MNUM",
}


def parse_zmx(text: str, source: str = "<zmx>", *, strict: bool = True, name: str = "lens") -> ZemaxImport:
    """Parse .zmx text into a :class:`ZemaxImport` (see :func:`read_zmx`)."""
    p = _Parser(source, strict)
    lines = text.splitlines()
    for lineno, line in enumerate(lines, 1):
        p.feed(lineno, line)
    end = len(lines)
    data = _build(p, end, name)
    return ZemaxImport(data, source, p.ignored, p.notes)


def _build(p: _Parser, end: int, name: str) -> dict:
    h = p.hdr
    scale = UNITS_MM[h.get("unit", "MM")]
    if "unit" not in h:
        p.notes.append("no UNIT line: millimetres assumed")
    if "aperture" not in h:
        p.fail(end, "ENPD", "no aperture definition (ENPD, FNUM, FLOA or OBNA) in the file (truncated file?)")
    if len(p.surfs) < 3:
        p.fail(
            end,
            "SURF",
            f"{len(p.surfs)} surface(s); a lens needs the object surface, at least one "
            "surface and the image surface (truncated file?)",
        )

    _check_pickups(p)
    obj, image, body = p.surfs[0], p.surfs[-1], p.surfs[1:-1]
    finite_object = not math.isinf(obj["disz"])
    if finite_object and obj["disz"] < 0:
        p.fail(
            obj["lines"].get("DISZ", obj["line"]),
            "DISZ",
            f"object distance {obj['disz']:g}: a virtual object (negative DISZ on SURF 0) is not supported",
        )
    if obj["curv"] != 0 and finite_object:
        p.fail(obj["lines"].get("CURV", obj["line"]), "CURV", "curved object surfaces are not supported")
    if h["aperture"][0] == "object_na" and not finite_object:
        p.fail(
            h["aperture_line"],
            "OBNA",
            "object-space NA with the object at infinity (DISZ INFINITY) defines no pupil: give ENPD, FNUM or FLOA",
        )
    if "glas" in obj:
        p.fail(obj["glas"][0], "GLAS", "object space must be air")
    # The last SURF is the image; a glass there means the file was cut short.
    if "glas" in image:
        p.fail(
            image["glas"][0],
            "GLAS",
            f"{p.where(image)} is the last surface, taken as the image "
            "plane, but has glass after it: the file looks truncated",
        )
    if image.get("coni", 0.0) != 0 and image["curv"] != 0:
        p.fail(
            image["lines"]["CONI"],
            "CONI",
            f"{p.where(image)} (image): a conic image surface is not supported (a spherical or flat one is)",
        )
    if image["type"] != "STANDARD" or any(v != 0 for v, _ in image["parm"].values()):
        p.fail(image["line"], "SURF", f"{p.where(image)} (image) must be a plain STANDARD surface")
    if image["disz"] != 0:  # OpticStudio always writes DISZ 0 on the image surface
        p.fail(
            image["lines"].get("DISZ", image["line"]),
            "DISZ",
            f"{p.where(image)}, the last surface, is taken as the image plane but has thickness "
            f"{image['disz']:g} after it: the file looks truncated",
        )
    stops = [s for s in body if s.get("stop")]
    if obj.get("stop") or image.get("stop"):
        p.fail(
            (obj if obj.get("stop") else image)["lines"]["STOP"],
            "STOP",
            "the stop must be one of the lens surfaces, not the object or the image",
        )
    if not stops:
        p.fail(end, "STOP", "no surface is marked STOP (the aperture stop must be given)")

    surfaces = [_surface(p, s, scale, last=s is body[-1]) for s in body]
    out: dict[str, Any] = {"name": h.get("name") or name, "units": "mm"}
    out["description"] = f"Imported from Zemax file {display_name(Path(p.source).name)}"
    if scale != 1:
        out["description"] += f" (lens units {h['unit']}, converted to mm)"
    kind, value = h["aperture"]
    if kind == "floa":
        out["aperture"] = {"type": "epd", "value": 1.0}  # replaced below, once glass is known
    else:
        out["aperture"] = {"type": kind, "value": value * scale if kind == "epd" else value}
    if finite_object:
        out["object_distance"] = obj["disz"] * scale
    fields = _fields(p, end, finite_object)
    heights = fields.pop("object_heights", None)  # (line, values): placed once glass is known
    image_heights = fields.pop("image_heights", None)
    out.update(fields)
    out.update(_waves(p, end))
    out["surfaces"] = surfaces
    img_sd = (
        image.get("clap")
        if "clap" in image
        else (image["diam"][0] if "diam" in image and image["diam"][1] == 1 else None)
    )
    if "diam" in image and image["diam"][1] != 1 and "clap" not in image:
        p.ignored.append((image["lines"]["DIAM"], "DIAM", "automatic image semi-diameter (not a clear aperture)"))
    out["image"] = {"semi_diameter": img_sd * scale if img_sd else None}
    if image["curv"] != 0:  # a curved sensor: traced to the sphere (docs/zemax.md)
        out["image"]["radius"] = _radius(image["curv"]) * scale
        if img_sd and abs(image["curv"]) * img_sd >= 1:
            p.fail(
                image["lines"].get("DIAM", image["line"]),
                "DIAM",
                f"{p.where(image)} (image): "
                f"semi-diameter {img_sd:g} exceeds the curved image surface (radius {_radius(image['curv']):g})",
            )
    if "DISZ" not in image["lines"]:  # OpticStudio (and our writer) write DISZ in every SURF block
        p.fail(
            end,
            "SURF",
            f"{p.where(image)}, the last surface (taken as the image plane), has no "
            "DISZ line: the file looks truncated",
        )
    _drop_crossing_diams(p, body, out["surfaces"])
    if kind == "floa":
        _resolve_floa(p, out, h["aperture_line"])
    if heights:
        _object_heights_to_angles(p, out, scale, *heights)
    if image_heights:
        _image_heights_to_angles(p, out, scale, *image_heights)
    if math.isinf(body[-1]["disz"]):
        _image_at_infinity(p, body[-1], out)
    _note_extrapolated_glass(p, body, out)
    return out


def _check_pickups(p: _Parser):
    """Parameter pickups (PPAR): the PARM value written with each is imported; a pickup
    that disagrees with it (a hand-edited file) is noted, one that names no PARM is an error."""
    for s in p.surfs:
        for n, (line, src, scale, offset, column) in sorted(s.get("ppar", {}).items()):
            if n not in s["parm"]:
                p.fail(
                    line,
                    "PPAR",
                    f"{p.where(s)}: pickup solve on parameter {n}, but the surface "
                    f"has no PARM {n} line with its value (truncated file?)",
                )
            value = s["parm"][n][0]
            source = p.surfs[src] if 0 <= src < len(p.surfs) else None
            from_n = column or n
            if source is None or from_n not in source["parm"]:
                p.ignored.append(
                    (
                        line,
                        "PPAR",
                        "parameter pickup solve (its source is not a parameter "
                        "of this file; the PARM value written with it is imported)",
                    )
                )
                continue
            picked = scale * source["parm"][from_n][0] + offset
            if abs(picked - value) > 1e-9 * max(1.0, abs(value), abs(picked)):
                p.notes.append(
                    f"line {line}: {p.where(s)}: PPAR picks up {picked:.12g} for parameter {n} "
                    f"(SURF {src} x {scale:g} + {offset:g}) but PARM {n} holds {value:.12g}; "
                    "the PARM value is imported"
                )
            else:
                p.ignored.append(
                    (
                        line,
                        "PPAR",
                        "parameter pickup solve (agrees with the PARM value written with it, which is imported)",
                    )
                )


def _surface(p: _Parser, s: dict, scale: float, last: bool = False) -> dict:
    c = s["curv"]
    surf: dict[str, Any] = {"radius": "inf" if c == 0 else _radius(c) * scale, "thickness": s["disz"] * scale}
    if math.isinf(s["disz"]):
        if not last:
            p.fail(s["lines"]["DISZ"], "DISZ", f"{p.where(s)}: infinite thickness inside the lens")
        surf["thickness"] = 0.0  # image at infinity: placed once the focus is known (_image_at_infinity)
    surf["material"] = _material(p, s)
    if s.get("coni", 0.0) != 0:
        surf["conic"] = s["coni"]
    asph = {}
    for i, (v, line) in sorted(s["parm"].items()):
        if v == 0:
            continue
        if s["type"] == "EVENASPH" and 1 <= i <= N_EVENASPH:
            power = 2 * i  # PARM i: coefficient of r^(2i)
        elif s["type"] == "ODDASPHE" and 1 <= i <= N_ODDASPHE:
            power = i  # PARM i: coefficient of r^i (odd powers too: r^1 alone is an axicon)
        else:
            p.fail(
                line,
                "PARM",
                f"{p.where(s)}: PARM {i} = {v:g} has no meaning on a {s['type']} surface"
                + {"EVENASPH": " (EVENASPH uses PARM 1-8)", "ODDASPHE": " (ODDASPHE uses PARM 1-8)"}.get(s["type"], ""),
            )
        asph[f"a{power}"] = v * scale ** (1 - power)  # a_k has units length^(1-k)
    if asph:
        surf["aspheric"] = asph
    sd = None
    if "clap" in s:
        sd = s["clap"]
    elif "diam" in s:
        sd = s["diam"][0]
    elif "flap" in s:  # FLAP carries the semi-diameter itself
        sd = s["flap"]
        if sd <= 0:
            # A floating aperture follows the surface's semi-diameter; without a DIAM that is
            # OpticStudio's automatic one (the beam's footprint), so it clips nothing.
            p.notes.append(
                f"line {s['lines']['FLAP']}: {p.where(s)}: floating aperture (FLAP) with "
                "no value and no DIAM: automatic semi-diameter, no clear aperture"
            )
            sd = None
        elif sd < 0:
            p.fail(s["lines"]["FLAP"], "FLAP", f"{p.where(s)}: negative floating aperture {sd:g}")
    if sd:
        surf["semi_diameter"] = sd * scale
    if s.get("stop"):
        surf["stop"] = True
    if s.get("comm"):
        surf["name"] = s["comm"]
    return surf


def _material(p: _Parser, s: dict):
    if "glas" not in s:
        return "air"
    line, tok = s["glas"]
    name = tok[1]
    solve = p.int_(line, "GLAS", tok, 2, 0, what="glass solve type")
    nd = p.num(line, "GLAS", tok, 4, 0.0)
    vd = p.num(line, "GLAS", tok, 5, 0.0)
    if name.upper() == "MIRROR":
        p.fail(line, "GLAS", f"{p.where(s)}: mirrors are not supported (refractive systems only)")
    if solve == 1:  # model glass: GLAS ___BLANK 1 0 nd vd dPgF ...
        dpgf = p.num(line, "GLAS", tok, 6, 0.0)
        if dpgf != 0:
            p.fail(
                line,
                "GLAS",
                f"{p.where(s)}: model glass dPgF = {dpgf:g} is not supported "
                "(optix model glass has no partial-dispersion term)",
            )
        if nd <= 0:
            p.fail(line, "GLAS", f"{p.where(s)}: model glass needs nd > 0, got {nd:g}")
        return {"n": nd} if vd == 0 else {"nd": nd, "vd": vd}
    if solve != 0:
        p.fail(
            line,
            "GLAS",
            f"{p.where(s)}: glass solve type {solve} (pickup/offset/substitute) is not supported; fix the glass first",
        )
    if name.upper() in ("___BLANK", "MODEL"):
        p.fail(line, "GLAS", f"{p.where(s)}: {name} without the model flag (GLAS {name} 1 0 nd vd)")
    return _catalog_glass(p, line, s, name, nd, vd)


#: (nd, vd) OpticStudio writes on a GLAS line when it did not fill in the glass's data.
_PLACEHOLDER_ND_VD = (1.5, 40.0)


def _recorded_index_usable(nd: float, vd: float) -> bool:
    """A GLAS line's recorded (nd, vd) describes the glass: nd > 1, vd >= 0, and not the
    placeholder (1.5, 40)."""
    return nd > 1 and vd >= 0 and (nd, vd) != _PLACEHOLDER_ND_VD


def _nd_vd(g) -> tuple[float, float]:
    """Catalog nd and Abbe number vd (d, F, C lines) of a resolved glass."""
    nd, nf, nc = (float(g.n(w)) for w in (0.5875618, 0.4861327, 0.6562725))
    return nd, (nd - 1) / (nf - nc)


def _catalog_glass(p: _Parser, line: int, s: dict, name: str, nd: float, vd: float) -> dict:
    """Find ``name`` in the file's GCAT catalogs only (in order), as OpticStudio does; a
    file without GCAT searches every catalog.  Several hits: the one nearest the (nd, vd)
    recorded on the GLAS line.  Not found: an error naming the catalogs that have it."""
    gcat_names = p.hdr.get("gcat", [])
    cats: list[str | None] = []
    for c in gcat_names:
        mapped = GCAT_TO_CATALOG.get(c.upper(), c.lower())
        cats.extend([mapped] if isinstance(mapped, str) else mapped)
    known = set(_glass.catalogs())
    searched = [c for c in cats if c in known] if gcat_names else [None]
    hits = []
    for cat in searched:
        try:
            hits.append(_glass.resolve(name, cat))
        except _glass.GlassError:
            continue
    if not hits:
        if _recorded_index_usable(nd, vd):
            # The file's own (nd, vd) for a glass we lack: a model glass, said so.
            p.notes.append(
                f"{p.where(s)}: glass {name} is not in the glass database (GCAT "
                f"{' '.join(gcat_names)}); imported as a model glass from the nd {nd:g}, "
                f"vd {vd:g} on line {line} (dispersion away from the d line is approximate)"
            )
            return {"nd": nd, "vd": vd} if vd > 0 else {"n": nd}
        successor = _successor_glass(name, searched)
        if successor is not None:
            snd, svd = _nd_vd(successor)
            p.notes.append(
                f"{p.where(s)}: glass {name} (line {line}) is not in the glass database "
                f"(GCAT {' '.join(gcat_names) or 'none'}) and the GLAS line records no nd/vd; "
                f"imported as {successor.name} ({successor.catalog}, nd {snd:.5f}, vd {svd:.2f}), "
                "its vendor's newer name for it or another vendor's equivalent of that name: check the indices"
            )
            return {"glass": successor.name, "catalog": successor.catalog}
        try:
            elsewhere = _glass.resolve(name)
            where = (
                f"; not substituted: {name} exists in catalog {elsewhere.catalog} "
                f"(add {elsewhere.catalog.upper()} to GCAT to use it)"
            )
        except _glass.GlassError as exc:
            where = "; " + str(exc).split("; ", 1)[-1]
        recorded = (
            "; the GLAS line records no nd/vd to import it as a model glass"
            if nd <= 1
            else f"; the GLAS line's nd {nd:g}, vd {vd:g} is OpticStudio's placeholder, not the glass's data"
        )
        p.fail(
            line,
            "GLAS",
            f"{p.where(s)}: unknown glass {name!r} in the file's catalogs "
            f"(GCAT {' '.join(gcat_names)}){where}{recorded}",
        )
    g = hits[0]  # molded glasses (LightPath's D-ZK3M, RPO's *_MOLD) carry the molder's own data
    if nd > 1 and len(hits) > 1:  # nearest (nd, vd); ties keep the GCAT order
        g = min(hits, key=lambda h: abs(_nd_vd(h)[0] - nd) + abs(_nd_vd(h)[1] - vd) * 1e-3)
    return {"glass": g.name, "catalog": g.catalog}


def _successor_glass(name: str, catalogs: list):
    """The first of :func:`successor_names` found in the searched catalogs, or None."""
    for cat in catalogs:
        for cand, cand_cat in successor_names(name, cat):
            try:
                return _glass.resolve(cand, cand_cat)
            except _glass.GlassError:
                continue
    return None


def _fields(p: _Parser, end: int, finite_object: bool = False) -> dict:
    h = p.hdr
    if "yfld" not in h:
        p.fail(end, "YFLN", "no field definition (YFLN) in the file (truncated file?)")
    line, key, ys = h["yfld"]
    n = h.get("n_fields", len(ys))
    if n < 1 or n > len(ys):
        p.fail(line, key, f"FTYP declares {n} fields but {key} lists {len(ys)} values")
    ys = ys[:n]
    if "xfld" in h:
        xline, xkey, xs = h["xfld"]
        if any(x != 0 for x in xs[:n]):
            p.fail(
                xline,
                xkey,
                "x field angles are not supported (fields lie along +y; "
                "a rotationally symmetric lens needs only the radial angle)",
            )
    fline, ftype = h.get("ftype", (line, 0))
    if ftype == 1 and finite_object:
        # object heights: angles once the entrance pupil is known (_object_heights_to_angles)
        for y in ys:
            if y < 0:
                p.fail(line, key, f"negative object height {y:g}: give fields along +y")
        return {"fields_deg": [0.0] * len(ys), "object_heights": (line, ys)}
    if ftype == 2:
        # paraxial image heights: angles once the paraxial optics are known (_image_heights_to_angles)
        for y in ys:
            if y < 0:
                p.fail(line, key, f"negative image height {y:g}: give fields along +y")
        return {"fields_deg": [0.0] * len(ys), "image_heights": (line, ys)}
    if ftype != 0:  # only the on-axis field means the same in every field type
        if any(y != 0 for y in ys):
            kinds = {1: "object height", 2: "paraxial image height", 3: "real image height", 4: "theodolite angle"}
            p.fail(
                fline,
                "FTYP",
                f"field type {ftype} ({kinds.get(ftype, 'unknown')}); only angle "
                "fields (type 0), paraxial image heights (type 2) and, for a finite object, object "
                "heights (type 1) are supported",
            )
        p.notes.append(f"field type {ftype} with only the on-axis field: read as angle 0")
    for y in ys:
        if y < 0:
            p.fail(line, key, f"negative field angle {y:g}: give fields along +y")
    return {"fields_deg": ys}


def _waves(p: _Parser, end: int) -> dict:
    n = p.hdr.get("n_waves", len(p.wavm))
    slots = list(range(1, n + 1))
    missing = [i for i in slots if i not in p.wavm]
    if n < 1 or missing:
        p.fail(end, "WAVM", f"{n} wavelength(s) declared but slot(s) {missing or [1]} not given (truncated file?)")
    for i in sorted(p.wavm):
        if i > n:
            p.ignored.append((p.wavm[i][2], "WAVM", f"inactive wavelength slot (FTYP declares {n})"))
    wl = [_from_um(p.wavm[i][0]) for i in slots]
    w = [p.wavm[i][1] for i in slots]
    for i in slots:
        if p.wavm[i][0] <= 0:
            p.fail(p.wavm[i][2], "WAVM", f"wavelength {i} must be > 0 um, got {p.wavm[i][0]:g}")
    line, pw = p.hdr.get("pwav", (end, 1))
    if not 1 <= pw <= n:
        p.fail(line, "PWAV", f"primary wavelength {pw} outside 1..{n}")
    return {"wavelengths_nm": wl, "wavelength_weights": w, "primary_wavelength_nm": wl[pw - 1]}


def _engine_on(p: _Parser, out: dict, line: int, key: str, what: str, fn, **kwargs):
    """The engine function ``fn`` (optix_e2e.engine) on the lens built so far (resolved), its
    error one ZemaxError naming the line and keyword that needed it."""
    import json

    from ..prescription import PrescriptionError, resolve_prescription

    try:
        return fn(json.dumps(resolve_prescription(out, p.source)), **kwargs)
    except (PrescriptionError, engine.EngineError) as exc:
        raise ZemaxError(f"{p.source}:{line}: {key}: cannot {what}: {exc}") from None


def _indices(p: _Parser, out: dict, line: int, key: str, what: str) -> list[float]:
    """Refractive indices of the media (object space first) at the primary wavelength."""
    return list(
        _engine_on(p, out, line, key, what, engine.refractive_indices, wavelength_nm=out["primary_wavelength_nm"])
    )


def _marginal_heights(
    surfaces: list[dict], n: list[float], start: tuple[float, float] = (0.5, 0.0)
) -> list[tuple[float, float]]:
    """(y, n u) at each surface of a paraxial ray entering at the first vertex with `start`
    = (y, n u): by default the marginal ray of a unit EPD from an object at infinity (it
    enters parallel at height 1/2 wherever the pupil lies); the paraxial curvature of an
    asphere includes its r^2 term, as in the engine."""
    from ..surface import curvature

    (y, nu), out = start, []
    for i, s in enumerate(surfaces):
        c = curvature(s) + 2.0 * float((s.get("aspheric") or {}).get("a2", 0.0))
        nu -= y * c * (n[i + 1] - n[i])
        out.append((y, nu))
        y += float(s["thickness"]) * nu / n[i + 1]
    return out


def _resolve_floa(p: _Parser, out: dict, line: int):
    """FLOA: the EPD is whatever fills the stop's semi-diameter paraxially.  The
    paraxial stop height is linear in the EPD, so one trace at EPD = 1 gives it (a ray
    trace that needs no focal length: afocal systems float too)."""
    surfaces = out["surfaces"]
    i_stop = next(i for i, s in enumerate(surfaces) if s.get("stop"))
    stop = surfaces[i_stop]
    if not stop.get("semi_diameter"):
        p.fail(line, "FLOA", "aperture floats by stop size but the stop surface has no DIAM")
    n = _indices(p, out, line, "FLOA", "size the pupil")
    unit = abs(_marginal_heights(surfaces, n)[i_stop][0])
    if not unit > 1e-12:
        p.fail(
            line, "FLOA", f"cannot size the pupil: the stop (surface {i_stop + 1}) is at a paraxial image of the object"
        )
    epd = stop["semi_diameter"] / unit
    out["aperture"] = {"type": "epd", "value": epd}
    out["description"] += (
        f"; aperture FLOA (float by stop size): stop semi-diameter "
        f"{stop['semi_diameter']:.10g} mm -> paraxial EPD {epd:.10g} mm"
    )
    p.notes.append(f"FLOA resolved to EPD {epd:.10g} mm")


def _object_heights_to_angles(p: _Parser, out: dict, scale: float, line: int, heights: list[float]):
    """Object-height fields (FTYP 1) of a finite object as the angles optix takes: the
    object point at height h is the one whose chief ray leaves at atan(h / L) towards the
    paraxial entrance pupil's centre, L = object plane to entrance pupil (as OpticStudio
    defines angle fields for a finite object), so each field is the same object point."""
    par = _engine_on(p, out, line, "YFLN", "place the object-height fields", engine.paraxial)
    L = abs(float(par["object_to_pupil_mm"]))
    _height_fields(p, out, line, heights, scale, L, "object-height", f"object to entrance pupil {L:.10g} mm")


def _height_fields(
    p: _Parser, out: dict, line: int, heights: list[float], scale: float, per_tan: float, what: str, detail: str
):
    """Fields given as heights h (lens units) that are ``per_tan`` mm per unit tan(angle):
    the angles atan(h / per_tan), with a note."""
    angles = [math.degrees(math.atan(h * scale / per_tan)) for h in heights]
    if any(a >= 89.9 for a in angles):
        p.fail(line, "YFLN", f"{what} {max(heights):g} is beyond 89.9 deg of field")
    out["fields_deg"] = angles
    p.notes.append(
        f"line {line}: {what} fields {', '.join(f'{h:g}' for h in heights)} -> field angles "
        f"{', '.join(f'{a:.10g}' for a in angles)} deg ({detail})"
    )


def _image_heights_to_angles(p: _Parser, out: dict, scale: float, line: int, heights: list[float]):
    """Paraxial image-height fields (FTYP 2) as the angles optix takes. The paraxial image
    height is linear in tan(angle) (EFL tan(angle) from infinity; for a finite object the
    object height L tan(angle) times the magnification), so one paraxial trace at a known
    angle gives the slope (taken at the paraxial image, wherever the image plane is)."""
    probe_deg = 10.0
    out["fields_deg"] = [probe_deg]
    par = _engine_on(p, out, line, "YFLN", "place the image-height fields", engine.paraxial)
    k = abs(float(par["paraxial_image_height_mm"])) / math.tan(math.radians(probe_deg))
    if not (math.isfinite(k) and k > 1e-12):
        p.fail(line, "YFLN", "image-height fields of a system that forms no finite image (afocal)")
    _height_fields(
        p,
        out,
        line,
        heights,
        scale,
        k,
        "paraxial image-height",
        f"paraxial image height {k:.10g} mm per unit tan(angle)",
    )


def _image_at_infinity(p: _Parser, last: dict, out: dict):
    """An infinite last thickness puts the image at infinity; optix's image is a plane at a
    finite distance, so it goes to the paraxial focus (thickness = BFL, negative for a
    virtual focus); an afocal system keeps it on the last surface."""
    line = last["lines"]["DISZ"]
    n = _indices(p, out, line, "DISZ", "place the image")
    d = out.get("object_distance")
    # the axial marginal ray: parallel from infinity, or (y, u) = (d, 1) from a finite object
    y, nu = _marginal_heights(out["surfaces"], n, start=(0.5, 0.0) if d is None else (d, n[0]))[-1]
    if abs(nu) < 1e-15:
        p.notes.append(
            f"line {line}: {p.where(last)}: image at infinity of "
            + ("an afocal system" if d is None else "an object in the front focal plane")
            + ": the image plane is the last surface"
        )
        return
    dist = -y / (nu / n[-1])
    out["surfaces"][-1]["thickness"] = dist
    p.notes.append(
        f"line {line}: {p.where(last)}: image at infinity (DISZ INFINITY): the image plane "
        f"is put at the paraxial " + ("focus, BFL" if d is None else "image of the object,") + f" {dist:.10g} mm"
    )


def _drop_crossing_diams(p: _Parser, body: list[dict], surfaces: list[dict]):
    """A DIAM alone does not clip rays in OpticStudio; where two neighbouring surfaces
    would cross inside their DIAMs (a drawing size no real lens could have), the DIAM-only
    semi-diameters are dropped, with a note, and the beam decides (Lens checks that the
    surfaces do not cross inside the paraxial beam).  CLAP/FLAP apertures stay."""
    import numpy as np

    from ..surface import sag

    for i in range(len(surfaces) - 1):
        a, b = surfaces[i], surfaces[i + 1]
        if not (a.get("semi_diameter") and b.get("semi_diameter")):
            continue
        r = np.linspace(0.0, min(a["semi_diameter"], b["semi_diameter"]), 33)[1:]
        gap = float(a["thickness"]) + sag(b, r) - sag(a, r)
        if not np.any(gap < -1e-9):
            continue
        for s, surf in ((body[i], a), (body[i + 1], b)):
            if "clap" not in s and "flap" not in s:
                p.notes.append(
                    f"{p.where(s)}: DIAM {surf.pop('semi_diameter'):g} dropped: surfaces "
                    f"{i + 1} and {i + 2} would cross inside their DIAMs (a DIAM does not clip "
                    "in OpticStudio)"
                )


def _note_extrapolated_glass(p: _Parser, body: list[dict], out: dict):
    """Each catalog glass asked for wavelengths just past its data: a note (the engine
    extrapolates a little, as OpticStudio does, and refuses further out)."""
    for s, surf in zip(body, out["surfaces"]):
        m = surf["material"]
        if isinstance(m, dict) and "glass" in m:
            note = _glass.resolve(m["glass"], m.get("catalog")).extrapolation(out["wavelengths_nm"])
            if note:
                p.notes.append(f"{p.where(s)}: {note}")
