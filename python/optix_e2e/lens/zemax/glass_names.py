"""Successor names for glasses of older catalogs (the .zmx reader's last resort).

Vendors renamed their glasses when they reformulated them (lead- and arsenic-free
"eco" glasses from the 1990s on) and matched the new glass to the old one's nd and vd:
Schott's SK16 became N-SK16 and LaKN7 N-LAK7; Hikari's E- series became its J- series;
Hoya's FD1 became E-FD1, Ohara's plain names gained S-, CDGM's H-, Sumita's K-; a
trailing R, A, HS or -W marks a variant of one glass type.  A file from an older
OpticStudio may name the old glass and, when the catalog it was saved with lacked it
too, record no nd/vd to rebuild it.  The reader then imports the successor in the same
vendor's catalog and says so in its notes (docs/zemax.md).

Schott's classic names (F1, SK16, BAF10, ...) were the industry's common names; Hikari
still lists its equivalents of them under the same names, meant to match Schott's nd and
vd (its F2, SF1 and SK16 do to 1e-4: tests/lens/test_zemax_glasses.py).  For a Schott name
the database lacks, Hikari's glass of that name comes first, then Schott's N- successor.
"""

from __future__ import annotations

import re

#: Each vendor's renaming: prefixes its reformulated glasses carry (tried in order) and
#: prefixes an older name of its own may carry (taken off first).
VENDOR_PREFIXES = {
    "schott": (("N-",), ("N-",)),
    "hikari": (("J-", "E-"), ("E-", "J-")),
    "hoya": (("E-",), ("E-",)),
    "ohara": (("S-",), ("S-",)),
    "cdgm": (("H-",), ("H-",)),
    "sumita": (("K-",), ("K-",)),
}
#: Trailing variant marks of one glass type (reformulated, improved, high transmission).
SUFFIXES = ("-W", "HS", "R", "A")
#: Schott's names of the 1970s-90s put an N inside the type name: LAKN7, SSKN5, KZFSN4.
_INNER_N = re.compile(r"([A-Z]{2,5})N(\d+[A-Z]?)")


def successor_names(name: str, catalog: str) -> list[tuple[str, str]]:
    """(name, catalog) pairs the glass ``name`` of ``catalog`` may be found as in newer
    catalogs, most likely first (names upper case; the database lookup ignores case);
    never ``name`` in ``catalog`` itself, none for a catalog without a known renaming."""
    if catalog not in VENDOR_PREFIXES:
        return []
    equivalent = [(name.strip().upper(), "hikari")] if catalog == "schott" else []
    return equivalent + [(n, catalog) for n in _renamed(name, catalog)]


def _renamed(name: str, catalog: str) -> list[str]:
    """Names ``name`` may carry in ``catalog``'s newer editions."""
    new, old = VENDOR_PREFIXES[catalog]
    up = name.strip().upper()
    core = next((up[len(p) :] for p in old if up.startswith(p) and len(up) > len(p)), up)
    cores = [core]
    m = _INNER_N.fullmatch(core) if catalog == "schott" else None
    if m:
        cores.append(m.group(1) + m.group(2))
    for suf in SUFFIXES:
        for c in list(cores):
            if c.endswith(suf) and len(c) > len(suf) + 1:
                cores.append(c[: -len(suf)])
    out: list[str] = []
    for c in cores:
        for cand in (*(p + c for p in new), c):
            if cand != up and cand not in out:
                out.append(cand)
    return out
