#!/usr/bin/env python3
"""The Table 2-3 experiment for every image-quality task: end-to-end against the nominal
lens with fine-tuned processing, same budget, held-out images, exact optics.

    python benches/e2e_tasks.py --budget full --out runs/e2e [--tasks iq-software iq-hardware low-light]
                                [--seeds 0 1 2] [--optimizer alg1] [--config FILE.toml]

Runs `optix design` per task and seed (resumable: OUT/TASK with one seed, OUT/TASK-seedS with
several; a run with its results.json is not re-run), then writes OUT/table.csv, OUT/table.json and OUT/table.md: per task and camera the
held-out PSNR, SSIM, 1 - LPIPS and HaarPSI, and the paired end-to-end minus nominal
differences with their 95 % bootstrap intervals over images (the frame headline, and the
centre and corner apart where the runs evaluated them); plus the surrogate's PSF error at the
final design and the wall times. With several seeds, per task and metric: the per-seed
differences, their mean with Student's t interval over seeds (`seeds_ci95`: how much a training
run varies with its seed, the interval to quote) and the bootstrap over images of the
seed-averaged differences (`pooled_ci95_given_runs`: the runs taken as given). docs/e2e.md
quotes it. It measures; it asserts nothing.
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
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--seed", type=int, default=None, help="one seed (the same as --seeds S)")
    ap.add_argument("--optimizer", default="alg1")
    ap.add_argument("--config", default=None)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = [a.seed] if a.seed is not None else a.seeds
    rows, table, runs = [], {}, {}
    for task in a.tasks:
        for seed in seeds:
            run = out / (task if len(seeds) == 1 else f"{task}-seed{seed}")
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
                str(seed),
                "--optimizer",
                a.optimizer,
            ] + (["--config", a.config] if a.config else [])
            if (run / "results.json").is_file():  # finished: not re-run (re-evaluated when the code changed)
                print(f"{run}: finished already", flush=True)
            else:
                print(" ".join(cmd), flush=True)
                subprocess.run(cmd, check=True)
            res = json.loads((run / "results.json").read_text())
            runs[(task, seed)] = run
            table.setdefault(task, {})[seed] = res
            for who in ("nominal", "end_to_end"):
                rows.append(
                    {
                        "task": task,
                        "seed": seed,
                        "camera": who,
                        # the optics the run trained on (a resumed folder keeps its own settings)
                        "optics": (res.get("optics_model") or {}).get("mode", "surrogate"),
                        **{m: res[who][m] for m, _ in METRICS},
                        **{f"{m}_surrogate_optics": res[who]["surrogate"][m] for m, _ in METRICS},
                    }
                )
    with open(out / "table.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    keys = (
        "nominal",
        "end_to_end",
        "paired",
        "paired_by_position",
        "headline_position",
        "surrogate_psf_rel_l1_per_field",
        "training",
        "wall_s",
        "held_out",
        "lens_zmx",
        "start",
        "space",
        "optics_model",
    )
    doc = {t: {str(sd): {k: r[k] for k in keys if k in r} for sd, r in per.items()} for t, per in table.items()}
    if len(seeds) > 1:
        for task in table:
            doc[task]["seeds"] = over_seeds(task, seeds, table[task], runs)
    (out / "table.json").write_text(json.dumps(doc, indent=2))
    optics = sorted({r["optics"] for r in rows})
    lines = [
        f"Optics in the loop: {', '.join(optics)}"
        + (" (MIXED: some runs resumed folders made under another default)" if len(optics) > 1 else ""),
        "",
        "| task | seed | camera | " + " | ".join(h for _, h in METRICS) + " |",
        "|---|---|---|" + "---|" * len(METRICS),
    ]
    for task, per in table.items():
        for seed, res in per.items():
            for who, label in (("nominal", "nominal + fine-tuned processing"), ("end_to_end", "end-to-end")):
                lines.append(
                    f"| {task} | {seed} | {label} | " + " | ".join(f"{res[who][m]:.4f}" for m, _ in METRICS) + " |"
                )
            lines.append(f"| {task} | {seed} | difference (95 % CI over images) | " + diff_cells(res["paired"]) + " |")
            for pos, pr in res.get("paired_by_position", {}).items():
                if pos != res.get("headline_position"):
                    lines.append(f"| {task} | {seed} | difference at the {pos} | " + diff_cells(pr) + " |")
        if len(seeds) > 1:
            sm = doc[task]["seeds"]
            cells = []
            for m, _ in METRICS:
                pm = "lpips" if m == "one_minus_lpips" else m
                d, ci = sm[pm]["mean"], sm[pm]["seeds_ci95"]
                lo, hi = ci
                if pm == "lpips":
                    d, lo, hi = -d, -hi, -lo
                cells.append(f"{d:+.4f} [{lo:+.4f}, {hi:+.4f}]")
            lines.append(
                f"| {task} | mean of {len(seeds)} | difference (t interval over seeds) | " + " | ".join(cells) + " |"
            )
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def diff_cells(paired: dict) -> str:
    cells = []
    for m, _ in METRICS:
        pm = "lpips" if m == "one_minus_lpips" else m
        d, (lo, hi) = paired[pm]["mean"], paired[pm]["ci95"]
        if pm == "lpips":  # 1 - LPIPS: the difference changes sign
            d, lo, hi = -d, -hi, -lo
        cells.append(f"{d:+.4f} [{lo:+.4f}, {hi:+.4f}]")
    return " | ".join(cells)


def over_seeds(task: str, seeds: list[int], per: dict, runs: dict) -> dict:
    """Per metric: the per-seed paired means, their mean with Student's t interval over seeds,
    each seed's interval over images, and the images' bootstrap of the seed-averaged
    differences (end-to-end minus nominal; the frame headline's samples)."""
    from alg1_vs_vanilla import seeds_interval

    from optix_e2e.camera_design.evaluate import METRICS as EV_METRICS
    from optix_e2e.camera_design.evaluate import paired

    def held(run: Path, who: str) -> list[dict]:
        with open(run / "metrics.csv") as f:
            return [
                {**r, "radius": float(r["radius"]), **{m: float(r[m]) for m in EV_METRICS}}
                for r in csv.DictReader(f)
                if r["camera"] == who and r["optics"] == "exact"
            ]

    nom = [r for s in seeds for r in held(runs[(task, s)], "nominal")]
    e2e = [r for s in seeds for r in held(runs[(task, s)], "end_to_end")]
    pooled = paired(nom, e2e)
    out = {}
    for m in EV_METRICS:
        d = [per[s]["paired"][m]["mean"] for s in seeds]
        out[m] = {
            "per_seed": d,
            "mean": float(sum(d) / len(d)),
            "seeds_ci95": seeds_interval(d),
            "per_seed_ci95": [per[s]["paired"][m]["ci95"] for s in seeds],
            "pooled_ci95_given_runs": pooled[m]["ci95"],
        }
    return out


if __name__ == "__main__":
    main()
