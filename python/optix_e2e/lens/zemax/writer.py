"""Writing our JSON prescription as a .zmx file (docs/zemax.md)."""

from __future__ import annotations

from pathlib import Path

from ...io import write_bytes_atomic, write_text_atomic
from .. import glass as _glass
from .common import CATALOG_TO_GCAT, N_EVENASPH, N_ODDASPHE, ZEMAX_POLYMER_NAMES, ZemaxError
from .numbers import _curv, _to_um
from .reader import _nd_vd


def _f(v: float) -> str:
    return repr(float(v))  # shortest string that reads back to the same double


def zmx_text(data: dict, source: str = "<lens>", footprint: "list[float] | None" = None) -> str:
    """The .zmx text of an (unresolved, validated) prescription dict.

    Every surface gets a DIAM line, as OpticStudio writes them (other readers, DeepLens's
    among them, need one): a fixed semi-diameter (solve 1, with a CLAP) where the lens has
    one, else the automatic one (solve 0) from ``footprint``: the ray heights on the body
    surfaces and the image (``len(surfaces) + 1`` values, as :meth:`Lens.to_zmx` traces
    them; 0 where unknown)."""
    from ..prescription import resolve_prescription

    resolve_prescription(data, source)  # validate first: errors name the JSON location

    def fail(where, msg):
        raise ZemaxError(f"{source}: {where}: {msg}")

    lines = [
        "VERS 190513 80 123457 L123457",
        "MODE SEQ",
        f"NAME {data.get('name', 'lens')}",
        "PFIL 0 0 0",
        "LANG 0",
        "UNIT MM X W X CM MR CPMM",
    ]
    ap = data["aperture"]
    lines.append(
        {
            "epd": f"ENPD {_f(ap['value'])}",
            "fno": f"FNUM {_f(ap['value'])} 0",
            "object_na": f"OBNA {_f(ap['value'])} 0",
        }[ap["type"]]
    )
    lines += ["ENVD 2.0E+1 1 0", "GFAC 0 0"]
    glas, gcat = [], []
    for i, s in enumerate(data["surfaces"]):
        g = _glas_line(s["material"], f"surface {i + 1} (surfaces[{i}]) material", fail)
        glas.append(g[0] if g else None)
        if g and g[1] and g[1] not in gcat:
            gcat.append(g[1])
    if gcat:  # in our search order, so a bare name resolves as it does in JSON
        order = {c.upper(): i for i, c in enumerate(_glass.catalogs())}
        lines.append("GCAT " + " ".join(sorted(gcat, key=lambda c: order.get(c, len(order)))))
    fields = [float(f) for f in data["fields_deg"]]
    wls = [float(w) for w in data["wavelengths_nm"]]
    weights = [float(w) for w in data.get("wavelength_weights") or [1.0] * len(wls)]
    primary = float(data.get("primary_wavelength_nm", wls[len(wls) // 2]))
    if primary not in wls:
        fail("primary_wavelength_nm", f"{primary} is not one of wavelengths_nm (Zemax's PWAV is an index)")
    lines += [
        "RAIM 0 0 1 1 0 0 0 0 0",
        f"FTYP 0 0 {len(fields)} {len(wls)} 0 0 0",
        "XFLN " + " ".join("0" for _ in fields),
        "YFLN " + " ".join(_f(f) for f in fields),
        "FWGN " + " ".join("1" for _ in fields),
    ]
    lines += [f"WAVM {i} {_f(_to_um(w))} {_f(k)}" for i, (w, k) in enumerate(zip(wls, weights), 1)]
    lines.append(f"PWAV {wls.index(primary) + 1}")
    dist = data.get("object_distance")
    finite = dist is not None and not isinstance(dist, str)
    n_surf = len(data["surfaces"])
    auto = [0.0] * (n_surf + 1) if footprint is None else [float(h) for h in footprint]
    if len(auto) != n_surf + 1:
        fail("footprint", f"{len(auto)} heights for {n_surf} surfaces and the image")
    lines += [
        "SURF 0",
        "  TYPE STANDARD",
        "  CURV 0.0",
        f"  DISZ {_f(dist) if finite else 'INFINITY'}",
        '  DIAM 0 0 0 0 1 ""',
    ]
    for i, s in enumerate(data["surfaces"]):
        where = f"surface {i + 1} (surfaces[{i}])"
        lines.append(f"SURF {i + 1}")
        if s.get("name"):
            lines.append(f"  COMM {s['name']}")
        if s.get("stop"):
            lines.append("  STOP")
        asph = {k: float(v) for k, v in (s.get("aspheric") or {}).items() if v != 0}
        odd = any(int(k[1:]) % 2 for k in asph)  # odd powers: OpticStudio's odd asphere
        top = N_ODDASPHE if odd else 2 * N_EVENASPH
        high = [k for k in asph if int(k[1:]) > top]
        if high:
            fail(
                f"{where} aspheric",
                f"{', '.join(high)}: Zemax "
                + (f"ODDASPHE (needed for the odd terms) stops at a{N_ODDASPHE}" if odd else "EVENASPH stops at a16"),
            )
        lines.append(f"  TYPE {'ODDASPHE' if odd else 'EVENASPH' if asph else 'STANDARD'}")
        lines.append(f"  CURV {_f(_surface_curv(s))}")
        lines.append(f"  DISZ {_f(s['thickness'])}")
        if glas[i]:
            lines.append(f"  GLAS {glas[i]}")
        if s.get("conic"):
            lines.append(f"  CONI {_f(s['conic'])}")
        sd = s.get("semi_diameter")
        if sd:  # fixed semi-diameter plus a circular aperture: Zemax clips there too
            lines += [f'  DIAM {_f(sd)} 1 0 0 1 ""', f"  CLAP 0 {_f(sd)} 0"]
        else:  # automatic: the beam's footprint
            lines.append(f'  DIAM {_f(auto[i])} 0 0 0 1 ""')
        for k in sorted(asph, key=lambda k: int(k[1:])):
            # EVENASPH: PARM i is the r^(2i) term; ODDASPHE: PARM i is the r^i term
            lines.append(f"  PARM {int(k[1:]) if odd else int(k[1:]) // 2} {_f(asph[k])}")
    image = data.get("image") or {}
    img_curv = _surface_curv({"radius": image.get("radius")})  # a curved sensor, or 0
    lines += [
        f"SURF {len(data['surfaces']) + 1}",
        "  TYPE STANDARD",
        f"  CURV {_f(img_curv) if img_curv else '0.0'}",
        "  DISZ 0.0",
    ]
    isd = image.get("semi_diameter")
    if isd:
        lines += [f'  DIAM {_f(isd)} 1 0 0 1 ""', f"  CLAP 0 {_f(isd)} 0"]
    else:
        lines.append(f'  DIAM {_f(auto[n_surf])} 0 0 0 1 ""')
    return "\n".join(lines) + "\n"


def _surface_curv(s: dict) -> float:
    if "curvature" in s:
        return float(s["curvature"])
    r = s.get("radius")
    if r is None or isinstance(r, str):
        return 0.0
    return _curv(float(r))


def _glas_line(m, where: str, fail) -> "tuple[str, str | None] | None":
    """(GLAS arguments, GCAT catalog) for a material; None for air."""
    if isinstance(m, str) and m.strip().lower() == "air":
        return None
    if isinstance(m, str) or (isinstance(m, dict) and "glass" in m):
        g = _glass.resolve(m)
        name = ZEMAX_POLYMER_NAMES.get(g.name, g.name) if g.catalog == "organic" else g.name
        nd, vd = _nd_vd(g)  # recorded like OpticStudio does; the reader uses them to pick the vendor
        gcat = CATALOG_TO_GCAT.get(g.catalog, g.catalog.upper())
        return f"{name} 0 0 {nd:.10f} {vd:.8f} 0 0 0 0 0 0", gcat
    if isinstance(m, dict) and "nd" in m:
        return f"___BLANK 1 0 {_f(m['nd'])} {_f(m['vd'])} 0 0 0 0 0 0", None
    if isinstance(m, dict) and "n" in m:  # Vd = 0: no dispersion
        return f"___BLANK 1 0 {_f(m['n'])} 0 0 0 0 0 0 0", None
    fail(
        where,
        "a formula or tabulated material has no Zemax equivalent; use a catalog "
        'glass name or a model glass {"nd", "vd"}',
    )


def write_zmx(
    data: dict,
    path: "str | Path",
    *,
    encoding: str = "utf-8",
    source: str = "<lens>",
    footprint: "list[float] | None" = None,
) -> Path:
    """Write ``data`` as a .zmx file; ``encoding="utf-16"`` gives OpticStudio's own
    encoding (UTF-16 LE with a BOM)."""
    if encoding.lower().replace("_", "-") not in ("utf-8", "utf-16"):
        raise ZemaxError(f"encoding must be utf-8 or utf-16, got {encoding!r}")
    path = Path(path)
    text = zmx_text(data, source, footprint)
    if encoding.lower().replace("_", "-") == "utf-16":
        write_bytes_atomic(path, b"\xff\xfe" + text.replace("\n", "\r\n").encode("utf-16-le"))
    else:
        write_text_atomic(path, text)
    return path
