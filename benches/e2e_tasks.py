#!/usr/bin/env python3
"""The Table 2-3 experiment for every image-quality task: end-to-end against the nominal
lens with fine-tuned processing, same budget, held-out images, exact optics.

    python benches/e2e_tasks.py --budget full --out runs/e2e [--tasks iq-software iq-hardware low-light]
                                [--seed 0] [--optimizer alg1] [--config FILE.toml]

Runs `optix design` per task (resumable), then writes OUT/table.csv, OUT/table.json and
OUT/table.md: per task and camera the held-out PSNR, SSIM, 1 - LPIPS and HaarPSI, and the
paired end-to-end minus nominal differences with their 95 % bootstrap intervals; plus the
surrogate's PSF error at the final design and the wall times. docs/e2e.md quotes it. It
measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

METRICS = (("psnr_db", "PSNR (dB)"), ("ssim", "SSIM"), ("one_minus_lpips", "1 - LPIPS"), ("haarpsi", "HaarPSI"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=["iq-software", "iq-hardware", "low-light"])
    ap.add_argument("--budget", default="full")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--optimizer", default="alg1")
    ap.add_argument("--config", default=None)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, table = [], {}
    for task in a.tasks:
        run = out / task
        cmd = [
            sys.executable,
            "-m",
            "optix_e2e",
            "design",
            task,
            "--out",
            str(run),
            "--budget",
            a.budget,
            "--seed",
            str(a.seed),
            "--optimizer",
            a.optimizer,
        ] + (["--config", a.config] if a.config else [])
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)
        res = json.loads((run / "results.json").read_text())
        table[task] = res
        for who in ("nominal", "end_to_end"):
            rows.append(
                {
                    "task": task,
                    "camera": who,
                    **{m: res[who][m] for m, _ in METRICS},
                    **{f"{m}_surrogate_optics": res[who]["surrogate"][m] for m, _ in METRICS},
                }
            )
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (out / "table.json").write_text(
        json.dumps(
            {
                t: {
                    k: r[k]
                    for k in (
                        "nominal",
                        "end_to_end",
                        "paired",
                        "surrogate_psf_rel_l1_per_field",
                        "training",
                        "wall_s",
                        "held_out",
                        "lens_zmx",
                    )
                }
                for t, r in table.items()
            },
            indent=2,
        )
    )
    lines = ["| task | camera | " + " | ".join(h for _, h in METRICS) + " |", "|---|---|" + "---|" * len(METRICS)]
    for task, res in table.items():
        for who, label in (("nominal", "nominal + fine-tuned processing"), ("end_to_end", "end-to-end")):
            lines.append(f"| {task} | {label} | " + " | ".join(f"{res[who][m]:.4f}" for m, _ in METRICS) + " |")
        cells = []
        for m, _ in METRICS:
            pm = "lpips" if m == "one_minus_lpips" else m
            d, (lo, hi) = res["paired"][pm]["mean"], res["paired"][pm]["ci95"]
            if pm == "lpips":  # 1 - LPIPS: the difference changes sign
                d, lo, hi = -d, -hi, -lo
            cells.append(f"{d:+.4f} [{lo:+.4f}, {hi:+.4f}]")
        lines.append(f"| {task} | difference (95 % CI) | " + " | ".join(cells) + " |")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
