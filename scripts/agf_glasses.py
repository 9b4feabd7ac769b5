"""Build python/optix_e2e/bundled/glass/agf_glasses.json: the glasses of Zemax's vendor AGF
catalogs that the refractiveindex.info database lacks (withdrawn and older glasses,
mostly), so that a .zmx file naming one under its GCAT gets the vendor's own data.

    python scripts/agf_glasses.py AGF_FOLDER [--out python/optix_e2e/bundled/glass/agf_glasses.json]

AGF_FOLDER holds the public copies named in SOURCES (the KrakenOS catalog folder of
github.com/Garchupiter/Kraken-Optical-Simulator, KrakenOS/Cat). Each entry keeps the
formula (converted to the database's formula numbers), the coefficients of its CD line, the
range of its LD line and the NM line's nd and vd; an entry whose formula does not give
that nd to 1e-4 and vd to 0.5 is left out (a formula read wrongly cannot slip in; the
catalogs' own rounding of vd reaches 0.2).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
from optix_e2e.lens import glass as _glass  # noqa: E402

REPO = "github.com/Garchupiter/Kraken-Optical-Simulator, KrakenOS/Cat"
#: our catalog -> AGF files, newest first (a name in a newer file wins).
SOURCES = {
    "schott": ["schott-1.agf", "SCHOTT-2.AGF"],
    "hoya": ["HOYA20220711_include_obsolete.agf"],
    "hikari": ["hikari.agf"],
    "ohara": ["ohara.agf"],
    "sumita": ["sumita.agf"],
    "cdgm": ["cdgm.agf"],
    "lzos": ["lzos.agf"],
}
# (nikon.agf is left out: its formula-1 and -13 coefficients do not give its own NM lines'
# nd and vd, so this script cannot tell what they mean.)
D, F, C = 0.5875618, 0.4861327, 0.6562725


def _text(path: Path) -> str:
    raw = path.read_bytes()
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")) or raw[1:2] == b"\x00":
        return raw.decode("utf-16")
    return raw.decode("latin-1")


def to_database_formula(zf: int, cd: list[float]) -> tuple[int, list[float]] | None:
    """A Zemax formula's CD coefficients as the database's (formula, coefficients)."""
    if zf == 1:  # Schott: n^2 = a0 + a1 l^2 + a2 l^-2 + a3 l^-4 + a4 l^-6 + a5 l^-8
        exps = [2, -2, -4, -6, -8]
    elif zf == 12:  # Extended 2: ... + a6 l^4 + a7 l^6
        exps = [2, -2, -4, -6, -8, 4, 6]
    elif zf == 13:  # Extended 3: n^2 = a0 + a1 l^2 + a2 l^4 + a3 l^-2 + ... + a8 l^-12
        exps = [2, 4, -2, -4, -6, -8, -10, -12]
    elif zf in (2, 6):  # Sellmeier 1 (3 terms), Sellmeier 3 (4 terms): K_i l^2 / (l^2 - L_i)
        k = 3 if zf == 2 else 4
        return 2, [0.0, *cd[: 2 * k]]
    else:
        return None
    coeffs = [cd[0]]
    for a, e in zip(cd[1:], exps):
        coeffs += [a, float(e)]
    return 3, coeffs


def parse(path: Path):
    """(name, zemax formula, nd, vd, cd, (lo, hi), status) for each NM entry."""
    entry = None
    for line in _text(path).splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "NM":
            if entry:
                yield entry
            status = int(float(tok[7])) if len(tok) > 7 else 0
            entry = {
                "name": tok[1],
                "zf": int(float(tok[2])),
                "nd": float(tok[4]),
                "vd": float(tok[5]),
                "cd": [],
                "range": None,
                "status": status,
            }
        elif entry and tok[0] == "CD":
            entry["cd"] = [float(v) for v in tok[1:]]
        elif entry and tok[0] == "LD":
            entry["range"] = (float(tok[1]), float(tok[2]))
    if entry:
        yield entry


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "python" / "optix_e2e" / "bundled" / "glass" / "agf_glasses.json",
    )
    args = ap.parse_args()
    out: dict[str, dict] = {}
    kept = dropped = 0
    for catalog, files in SOURCES.items():
        table: dict[str, dict] = {}
        for fname in files:
            for e in parse(args.folder / fname):
                if e["name"] in table or not e["range"]:
                    continue
                try:
                    _glass.resolve(e["name"], catalog)
                    continue  # the database has it: its page wins
                except _glass.GlassError:
                    pass
                conv = to_database_formula(e["zf"], e["cd"])
                if conv is None:
                    dropped += 1
                    continue
                formula, coeffs = conv
                with np.errstate(all="ignore"):
                    nd, nf, nc = (float(_glass._eval_formula(formula, coeffs, w)) for w in (D, F, C))
                    vd = (nd - 1) / (nf - nc) if nf != nc else float("nan")
                if not (abs(nd - e["nd"]) <= 1e-4 and abs(vd - e["vd"]) <= 0.5):
                    print(
                        f"{catalog}/{e['name']}: formula {e['zf']} gives nd {nd:.6f}, vd "
                        f"{vd:.2f}, the NM line {e['nd']}, {e['vd']}: left out"
                    )
                    dropped += 1
                    continue
                table[e["name"]] = {
                    "formula": formula,
                    "coefficients": coeffs,
                    "range_um": list(e["range"]),
                    "nd": e["nd"],
                    "vd": e["vd"],
                    "obsolete": e["status"] == 2,
                    "source": f"Zemax {fname} ({REPO}/{fname})",
                }
                kept += 1
        out[catalog] = dict(sorted(table.items()))
    args.out.write_text(json.dumps(out, indent=0, separators=(",", ":")) + "\n")
    print(f"{kept} glasses written to {args.out} ({dropped} left out)")


if __name__ == "__main__":
    main()
