"""Build python/optix_e2e/bundled/glass/agf_glasses.json: the glasses of Zemax's vendor AGF
catalogs that the refractiveindex.info database lacks (withdrawn and older glasses,
mostly), so that a .zmx file naming one under its GCAT gets the vendor's own data.

    python scripts/agf_glasses.py AGF_FOLDER [AGF_FOLDER ...] [--only CATALOG ...] [--out ...json]

The AGF_FOLDERs hold the public copies named in SOURCES (the KrakenOS catalog folder of
github.com/Garchupiter/Kraken-Optical-Simulator, KrakenOS/Cat, and the AGF_files folder of
github.com/nzhagen/zemaxglass); each file is read from the first folder that has it. --only
rebuilds those catalogs and keeps the others as the file has them. Each entry keeps the
formula (converted to the database's formula numbers), the coefficients of its CD line, the
range of its LD line and the NM line's nd and vd; an entry whose formula does not give
that nd to 1e-4 and vd to 0.5 is left out (a formula read wrongly cannot slip in; the
catalogs' own rounding of vd reaches 0.2). An infrared material whose NM line has no d-line
data (nd 1, vd 0) is kept where its formula gives a finite index in (1, 5) over its whole LD
range (the formula readings themselves are checked by the glasses that have d-line data).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
from optix_e2e.io import write_text_atomic  # noqa: E402
from optix_e2e.lens import glass as _glass  # noqa: E402

KRAKEN = "github.com/Garchupiter/Kraken-Optical-Simulator, KrakenOS/Cat"
HAGEN = "github.com/nzhagen/zemaxglass, AGF_files"
#: our catalog -> (AGF file, where it is public), newest first (a name in a newer file wins).
#: rpo: RPO's moulded glasses (*_MOLD: the molder's data, a few 1e-3 below the annealed
#: glass); zeon: ZEON's cyclo-olefin polymers (E48R, 480R, 330R); infrared: Zemax's INFRARED
#: catalog (ZNS_IR, AMTIR1, ...: the crystals the database has stay its pages).
SOURCES = {
    "schott": [("schott-1.agf", KRAKEN), ("SCHOTT-2.AGF", KRAKEN)],
    "hoya": [("HOYA20220711_include_obsolete.agf", KRAKEN)],
    "hikari": [("hikari.agf", KRAKEN)],
    "ohara": [("ohara.agf", KRAKEN)],
    "sumita": [("sumita.agf", KRAKEN)],
    "cdgm": [("cdgm.agf", KRAKEN)],
    "lzos": [("lzos.agf", KRAKEN)],
    "rpo": [("rpo.agf", HAGEN)],
    "zeon": [("zeon.agf", HAGEN)],
    "infrared": [("infrared.agf", HAGEN)],
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
    elif zf in (2, 6, 11):  # Sellmeier 1 (3 terms), 3 (4 terms), 5 (5 terms): K_i l^2 / (l^2 - L_i)
        k = {2: 3, 6: 4, 11: 5}[zf]
        return 2, [0.0, *cd[: 2 * k]]
    elif zf == 3:  # Herzberger: n = A + B L + C L^2 + D l^2 + E l^4 + F l^6, L = 1 / (l^2 - 0.028)
        return 7, list(cd[:6])
    elif zf == 5:  # Conrady: n = n0 + A / l + B / l^3.5 (the database's formula 5, exponents written out)
        return 5, [cd[0], cd[1], -1.0, cd[2], -3.5]
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
    ap.add_argument("folders", type=Path, nargs="+")
    ap.add_argument("--only", nargs="+", choices=sorted(SOURCES), help="rebuild these catalogs only")
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "python" / "optix_e2e" / "bundled" / "glass" / "agf_glasses.json",
    )
    args = ap.parse_args()
    out: dict[str, dict] = json.loads(args.out.read_text()) if args.only else {}
    kept = dropped = 0
    for catalog, files in SOURCES.items():
        if args.only and catalog not in args.only:
            continue
        table: dict[str, dict] = {}
        for fname, repo in files:
            folder = next((f for f in args.folders if (f / fname).is_file()), None)
            if folder is None:
                sys.exit(f"{fname} is in none of {', '.join(map(str, args.folders))}")
            for e in parse(folder / fname):
                if e["name"] in table or not e["range"]:
                    continue
                try:
                    found = _glass.resolve(e["name"], catalog)
                    if found.path != f"builtin:{catalog}/{found.name}" or found.name in _glass.ZEMAX_NAMES.get(
                        catalog, {}
                    ):
                        continue  # the database (or a named entry) has it: its page wins
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
                if e["nd"] == 1.0 and e["vd"] == 0.0:  # no d-line data (an infrared material): its range instead
                    with np.errstate(all="ignore"):
                        n = _glass._eval_formula(formula, coeffs, np.linspace(*e["range"], 50))
                    if not (np.all(np.isfinite(n)) and np.all((n > 1.0) & (n < 5.0))):
                        print(
                            f"{catalog}/{e['name']}: formula {e['zf']} gives no index in (1, 5) over its range: left out"
                        )
                        dropped += 1
                        continue
                elif not (abs(nd - e["nd"]) <= 1e-4 and abs(vd - e["vd"]) <= 0.5):
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
                    "source": f"Zemax {fname} ({repo}/{fname})",
                }
                kept += 1
        out[catalog] = dict(sorted(table.items()))
    write_text_atomic(args.out, json.dumps(out, indent=0, separators=(",", ":")) + "\n")
    print(f"{kept} glasses written to {args.out} ({dropped} left out)")


if __name__ == "__main__":
    main()
