"""Summarise a dataset run's refusals and PSF methods (docs/accuracy.md, "Spots larger than
the window"):

    python benches/dataset_refusals.py DIR [DIR ...]

Per directory: designs written and failed, the failures by kind (the engine's PSF checks
"psf:", the trace's checks "trace:", focus, geometry), the PSF methods auto chose, how many
PSFs auto recorded as predicted above its target or flagged, and the shards' seconds per
design."""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path


def summarise(root: Path) -> dict:
    ok = failed = 0
    kinds: Counter = Counter()
    methods: Counter = Counter()
    warned: Counter = Counter()
    seconds = 0.0
    for meta in sorted(root.glob("shards/*/shard.json")):
        m = json.loads(meta.read_text())
        ok += m["n_ok"]
        failed += m["n_failed"]
        seconds += m["seconds"]
        for f in m["failures"]:
            reason = f["reason"]
            kind = reason.split(": ", 2)[1] if reason.startswith("field ") else reason.split(":", 1)[0]
            kinds[kind] += 1
        legend = m["psf_methods"]["legend"]
        for codes in m["psf_methods"]["codes"].values():
            methods.update(legend[c] for c in codes)
        for ws in m["warnings"].values():
            for w in ws:
                if "no method is predicted to meet" in w:
                    warned["predicted above the target"] += 1
                if "is flagged by its own checks" in w:
                    warned["flagged, nothing left to escalate to"] += 1
                if "failed its checks; escalated" in w:
                    warned["escalated"] += 1
    n = ok + failed
    return {
        "dir": str(root),
        "designs": n,
        "written": ok,
        "failed": failed,
        "failures_by_kind": dict(kinds),
        "psf_methods": dict(methods.most_common()),
        "psf_warnings": dict(warned),
        "seconds": round(seconds, 1),
        "seconds_per_design": round(seconds / n, 2) if n else None,
    }


def main(argv=None) -> int:
    for d in argv if argv is not None else sys.argv[1:]:
        print(json.dumps(summarise(Path(d)), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
