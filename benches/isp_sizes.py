#!/usr/bin/env python3
"""Software ISP size against quality and speed: parameters, milliseconds per megapixel, and the
validation figures each network's training recorded.

    python benches/isp_sizes.py --isp A/software_isp.pt --isp B/software_isp.pt [--out DIR]

For each checkpoint: its parameters; the forward pass's time per megapixel of RAW on this
machine (one ``--size`` x ``--size`` RAW crop, batch 1, float32, ``--threads`` torch threads, no
gradient; median of ``--repeats`` after one warm-up), the quantity that decides what the network
costs inside a design run and on a camera; and the last validation row of its training curve
(``meta["curve"]``: PSNR over all validation samples and per lens kind and light), with the
steps and minutes it had. Networks compared this way should share their training's data, loss,
steps and seed (docs/isp.md says which runs do). Writes sizes.json and sizes.md with ``--out``.
It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from optix_e2e.errors import InputError
from optix_e2e.isp.software import SoftwareISP

# The IMX249's half diagonal in pixels (1920 x 1200): the position channels' full field.
FULL_FIELD_PX = (960.0**2 + 600.0**2) ** 0.5


def ms_per_megapixel(isp: SoftwareISP, size: int, repeats: int) -> float:
    raw = torch.rand(1, 1, size, size, generator=torch.Generator().manual_seed(0)) * 4095.0
    times = []
    with torch.no_grad():
        isp(raw, (0.0, 0.0), FULL_FIELD_PX)  # warm-up
        for _ in range(repeats):
            t = time.perf_counter()
            isp(raw, (0.0, 0.0), FULL_FIELD_PX)
            times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3 / (size * size / 1e6)


def describe(path: Path, size: int, repeats: int) -> dict:
    isp = SoftwareISP.load(path)
    meta = getattr(isp, "meta", {}) or {}
    curve = meta.get("curve") or []
    last = curve[-1] if curve else {}
    cfg = isp.config()
    return {
        "checkpoint": str(path),
        "arch": cfg.get("arch"),
        "width": cfg.get("base"),
        "depth": cfg.get("depth"),
        "blocks": cfg.get("blocks"),
        "parameters": sum(p.numel() for p in isp.parameters()),
        "ms_per_megapixel": ms_per_megapixel(isp, size, repeats),
        "steps": meta.get("steps"),
        "minutes": meta.get("minutes"),
        "validation": {k: v for k, v in last.items() if k.startswith("psnr_db") or k in ("step", "loss")},
    }


def table(rows: list[dict]) -> str:
    kinds = [
        "psnr_db",
        "psnr_db_perfect_normal",
        "psnr_db_nominal_normal",
        "psnr_db_space_normal",
        "psnr_db_nominal_low",
    ]
    head = "| network | parameters | ms / MP | steps | " + " | ".join(
        k.removeprefix("psnr_db_") or "all" for k in kinds
    )
    head = head.replace("| psnr_db |", "| all |") + " |"
    lines = [head, "|" + "---|" * (5 + len(kinds) - 1)]
    for r in rows:
        v = r["validation"]
        cells = [f"{v[k]:.2f}" if isinstance(v.get(k), (int, float)) else "" for k in kinds]
        name = f"{r['arch']} width {r['width']}"
        lines.append(
            f"| {name} | {r['parameters']:,} | {r['ms_per_megapixel']:.0f} | {r['steps']} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--isp", type=Path, action="append", required=True, help="a software_isp.pt (repeatable)")
    ap.add_argument("--size", type=int, default=512, help="RAW crop side for the timing (even)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    if a.size < 2 or a.size % 2 or a.repeats < 1:
        raise SystemExit(f"--size must be even and >= 2, --repeats >= 1 (got {a.size}, {a.repeats})")
    try:
        rows = [describe(p, a.size, a.repeats) for p in a.isp]
    except InputError as err:  # a missing or foreign checkpoint: its one line
        raise SystemExit(str(err)) from None
    out = {"size_px": a.size, "threads": a.threads, "repeats": a.repeats, "networks": rows}
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "sizes.json").write_text(json.dumps(out, indent=2) + "\n")
        (a.out / "sizes.md").write_text(table(rows))
    print(table(rows), end="")
    return out


if __name__ == "__main__":
    main()
