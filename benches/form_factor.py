#!/usr/bin/env python3
"""Fewer elements, the same picture? Image quality against element count, total track and lens
mass, for the nominal and the end-to-end camera of each space (issue 57, docs/form-factor.md).

    python benches/form_factor.py --out DIR --test-photos data/photos/kodak24 \\
        --test-photos data/photos/mcmaster18 [--spaces paper-triplet paper-doublet] \\
        [--seeds 0 1 2] [--budget full] [--task iq-software] [--jobs 2] [--threads 1]

Runs `optix design TASK` per space and seed (resumable: DIR/runs/SPACE-seedS; a run whose
results.json has the test split is not run again; `--jobs` at a time, each on `--threads` torch
threads, its log beside it), the same budget, seeds and evaluation protocol for every space:
exact optics in the loop, the shipped processing fine-tuned on the run's budget, the untouched
test split (docs/test-split.md) at native scale. paper-triplet is the default space
(paper-triplet-e2e around the bundled triplet), paper-doublet the two-element one.

Writes DIR/form_factor.{json,md,csv} and DIR/form_factor.png: per space and camera (nominal lens
+ processing untuned, nominal + fine-tuned, end-to-end, and the ideal lens's ceiling) the test
split's PSNR, SSIM and 1 - LPIPS (frame positions, mean over seeds), the lens's element count,
total track, glass mass and RMS spot; the paired differences per seed (95 % bootstrap over the
photographs) and over seeds (Student's t over the seeds' mean differences): end-to-end minus
each space's nominal, and across spaces (the same photographs, positions and noise draws, seed
k against seed k). It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

SPACES = {  # name -> the design command's space option and the lens it starts from
    "paper-triplet": {"option": [], "lens": "paper-triplet"},
    "paper-doublet": {"option": ["--space", "paper-doublet"], "lens": "paper-doublet"},
}
CAMERAS = ("nominal_untuned", "nominal", "end_to_end", "ideal_lens")
METRICS = (("psnr_db", "PSNR (dB)"), ("ssim", "SSIM"), ("one_minus_lpips", "1 - LPIPS"))
# (label, (space, camera) minus (space, camera)): what users ask of a smaller lens
COMPARISONS = [
    ("{s} end-to-end minus {s} nominal + fine-tuned processing", ("{s}", "end_to_end"), ("{s}", "nominal")),
    ("{s} end-to-end minus {s} nominal + untuned processing", ("{s}", "end_to_end"), ("{s}", "nominal_untuned")),
]
CROSS = [
    (
        "doublet end-to-end minus triplet nominal + fine-tuned processing",
        ("paper-doublet", "end_to_end"),
        ("paper-triplet", "nominal"),
    ),
    ("doublet end-to-end minus triplet end-to-end", ("paper-doublet", "end_to_end"), ("paper-triplet", "end_to_end")),
    (
        "doublet nominal minus triplet nominal (both + fine-tuned processing)",
        ("paper-doublet", "nominal"),
        ("paper-triplet", "nominal"),
    ),
]


def run_one(run: Path, space: str, seed: int, a) -> str:
    res = run / "results.json"
    if res.is_file() and "test_split" in json.loads(res.read_text()):
        return f"{run.name}: done before"
    flags = f"--budget {a.budget} --seed {seed} --threads {a.threads} --quiet".split()
    cmd = [sys.executable, "-m", "optix_e2e", "design", a.task, "--out", str(run), *flags, *SPACES[space]["option"]]
    for p in a.test_photos:
        cmd += ["--test-photos", p]
    with open(run.with_suffix(".log"), "a") as log:
        rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    if rc != 0:
        raise SystemExit(f"{run.name}: optix design exited {rc} (log: {run.with_suffix('.log')})")
    return f"{run.name}: ran"


@cache  # each run's file is read once, however many comparisons pair it
def test_rows(run: Path, who: str) -> list[dict]:
    from optix_e2e.camera_design.evaluate import METRICS as EV

    with open(run / "test_metrics.csv") as f:
        return [
            {**r, "radius": float(r["radius"]), **{m: float(r[m]) for m in EV}}
            for r in csv.DictReader(f)
            if r["camera"] == who
        ]


def lens_facts(run: Path, who: str) -> dict:
    """Element count, total track, glass mass and RMS spot of a run's lens (its exported
    prescription, refocused, with the semi-diameters of its own footprint)."""
    from optix_e2e.lens import Lens
    from optix_e2e.lens.mass import lens_mass

    lens = Lens.load(run / "lens" / f"{who}.json")
    mass = lens_mass(lens.raw)
    rep = json.loads((run / "report" / who / "report.json").read_text())
    spots = [f["rms_spot_um"] for f in rep["fields"]]
    return {
        "elements": mass["n_elements"],
        "total_track_mm": float(lens.paraxial()["total_track_mm"]),
        "mass_g": mass["mass_g"],
        "rms_spot_um_per_field": spots,
        "fields_deg": [f["field_deg"] for f in rep["fields"]],
        "rms_spot_um_mean": float(np.mean(spots)),
    }


def difference(runs: dict, seeds: list[int], b: tuple, a: tuple) -> dict:
    """b minus a on the test split, per metric: per seed (paired over photographs, bootstrap),
    and over seeds (t interval of the seeds' means)."""
    from alg1_vs_vanilla import seeds_interval

    from optix_e2e.camera_design.evaluate import paired

    per = [paired(test_rows(runs[(a[0], s)], a[1]), test_rows(runs[(b[0], s)], b[1])) for s in seeds]
    out = {}
    for m, _ in METRICS:
        key = "lpips" if m == "one_minus_lpips" else m
        sign = -1.0 if m == "one_minus_lpips" else 1.0  # 1 - LPIPS: higher is better
        d = [sign * p[key]["mean"] + 0.0 for p in per]  # + 0.0: no "-0.000"
        cis = [sorted(sign * x + 0.0 for x in p[key]["ci95"]) for p in per]
        out[m] = {"per_seed": d, "per_seed_ci95": cis, "mean": float(np.mean(d)), "seeds_ci95": seeds_interval(d)}
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--test-photos", action="append", default=[], required=True)
    ap.add_argument("--spaces", nargs="+", default=list(SPACES), choices=list(SPACES))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--budget", default="full")
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    out = Path(a.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    runs = {(sp, s): out / "runs" / f"{sp}-seed{s}" for sp in a.spaces for s in a.seeds}
    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        for msg in pool.map(lambda kv: run_one(kv[1], kv[0][0], kv[0][1], a), runs.items()):
            print(msg, flush=True)

    table: dict = {"task": a.task, "budget": a.budget, "seeds": a.seeds, "test_photos": a.test_photos, "spaces": {}}
    for sp in a.spaces:
        res = {s: json.loads((runs[(sp, s)] / "results.json").read_text()) for s in a.seeds}
        cams = {}
        for who in CAMERAS:
            vals = {m: [res[s]["test_split"]["means"][who][m] for s in a.seeds] for m, _ in METRICS}
            cams[who] = {m: {"per_seed": v, "mean": float(np.mean(v))} for m, v in vals.items()}
            # PSNR at each evaluated position (frame: the headline; centre; corner), mean over seeds
            by = [res[s]["test_split"]["means"][who].get("by_position", {}) for s in a.seeds]
            cams[who]["psnr_db_by_position"] = {
                p: float(np.mean([b[p]["psnr_db"] for b in by])) for p in by[0] if all(p in b for b in by)
            }
        table["spaces"][sp] = {
            "nominal_lens": lens_facts(runs[(sp, a.seeds[0])], "nominal"),
            "end_to_end_lens": {s: lens_facts(runs[(sp, s)], "end_to_end") for s in a.seeds},
            "test_split": cams,
            "development_set_psnr_db": {
                who: float(np.mean([res[s][who]["psnr_db"] for s in a.seeds])) for who in ("nominal", "end_to_end")
            },
            "wall_s": [res[s]["wall_s"] for s in a.seeds],
        }
    comps = {}
    for sp in a.spaces:
        for label, b, c in COMPARISONS:
            comps[label.format(s=sp)] = difference(runs, a.seeds, (sp, b[1]), (sp, c[1]))
    if {"paper-triplet", "paper-doublet"} <= set(a.spaces):
        for label, b, c in CROSS:
            comps[label] = difference(runs, a.seeds, b, c)
    table["differences"] = comps
    (out / "form_factor.json").write_text(json.dumps(table, indent=1))
    write_csv(out / "form_factor.csv", table)
    (out / "form_factor.md").write_text(markdown(table))
    chart(out / "form_factor.png", table)
    print((out / "form_factor.md").read_text())


def write_csv(path: Path, t: dict) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["space", "camera", "elements", "total_track_mm", "mass_g", *(m for m, _ in METRICS)])
        for sp, d in t["spaces"].items():
            lens = d["nominal_lens"]
            for who in CAMERAS:
                w.writerow(
                    [
                        sp,
                        who,
                        lens["elements"],
                        f"{lens['total_track_mm']:.3f}",
                        f"{lens['mass_g']:.4f}",
                        *(f"{d['test_split'][who][m]['mean']:.4f}" for m, _ in METRICS),
                    ]
                )


def _ci(x: list | None) -> str:
    return f"[{x[0]:+.3f}, {x[1]:+.3f}]" if x else "-"


def markdown(t: dict) -> str:
    n = len(t["seeds"])
    lines = [
        f"# Form factor: {t['task']}, budget {t['budget']}, seeds {', '.join(map(str, t['seeds']))}",
        "",
        "Test split (docs/test-split.md, frame positions), exact optics, means over the seeds.",
        "",
        "| space | elements | total track (mm) | glass (g) | nominal RMS spot, mean of fields (um) | camera | PSNR (dB) | SSIM | 1 - LPIPS |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for sp, d in t["spaces"].items():
        L = d["nominal_lens"]
        for who in CAMERAS:
            c = d["test_split"][who]
            lines.append(
                f"| {sp} | {L['elements']} | {L['total_track_mm']:.1f} | {L['mass_g']:.2f} | {L['rms_spot_um_mean']:.1f} "
                f"| {who} | {c['psnr_db']['mean']:.3f} | {c['ssim']['mean']:.4f} | {c['one_minus_lpips']['mean']:.4f} |"
            )
    lines += ["", "Test-split PSNR (dB) by position, mean over the seeds:", ""]
    positions = sorted(
        {p for d in t["spaces"].values() for c in d["test_split"].values() for p in c["psnr_db_by_position"]}
    )
    lines += ["| space | camera | " + " | ".join(positions) + " |", "|---|---|" + "---|" * len(positions)]
    for sp, d in t["spaces"].items():
        for who in CAMERAS:
            by = d["test_split"][who]["psnr_db_by_position"]
            lines.append(
                f"| {sp} | {who} | " + " | ".join(f"{by[p]:.2f}" if p in by else "-" for p in positions) + " |"
            )
    lines += ["", "The lenses (RMS spot per field, um; the end-to-end lens of each seed, refocused):", ""]
    lines += ["| space | lens | total track (mm) | glass (g) | RMS spot per field |", "|---|---|---|---|---|"]
    for sp, d in t["spaces"].items():
        lenses = [("nominal", d["nominal_lens"])] + [
            (f"end-to-end, seed {s}", v) for s, v in d["end_to_end_lens"].items()
        ]
        for name, L in lenses:
            spots = " / ".join(f"{x:.1f}" for x in L["rms_spot_um_per_field"])
            lines.append(f"| {sp} | {name} | {L['total_track_mm']:.2f} | {L['mass_g']:.3f} | {spots} |")
    lines += [
        "",
        f"Differences (b minus a; per seed the 95 % bootstrap over photographs, over the {n} seeds Student's t):",
        "",
    ]
    lines += ["| comparison | metric | per seed | mean | over seeds |", "|---|---|---|---|---|"]
    for label, d in t["differences"].items():
        for m, name in METRICS:
            x = d[m]
            per = "; ".join(f"{v:+.3f} {_ci(ci)}" for v, ci in zip(x["per_seed"], x["per_seed_ci95"]))
            lines.append(f"| {label} | {name} | {per} | {x['mean']:+.3f} | {_ci(x['seeds_ci95'])} |")
    return "\n".join(lines) + "\n"


def chart(path: Path, t: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(METRICS), figsize=(4.2 * len(METRICS), 3.6))
    style = {
        "nominal_untuned": ("s", "0.6"),
        "nominal": ("o", "tab:blue"),
        "end_to_end": ("D", "tab:red"),
        "ideal_lens": ("_", "0.3"),
    }
    for ax, (m, name) in zip(axes, METRICS):
        for k, d in enumerate(t["spaces"].values()):
            L = d["nominal_lens"]
            x0 = L["elements"]
            for j, who in enumerate(CAMERAS):
                v = d["test_split"][who][m]["per_seed"]
                x = x0 + 0.08 * (j - 1.5)
                mk, col = style[who]
                ax.scatter([x] * len(v), v, marker=mk, color=col, s=14, alpha=0.5)
                ax.scatter(
                    [x], [np.mean(v)], marker=mk, color=col, s=50, label=who.replace("_", " ") if k == 0 else None
                )
        ticks = {d["nominal_lens"]["elements"]: (sp, d["nominal_lens"]) for sp, d in t["spaces"].items()}
        ax.set_xticks(sorted(ticks))
        ax.set_xticklabels(
            [
                f"{n}: {ticks[n][0]}\n{ticks[n][1]['total_track_mm']:.1f} mm, {ticks[n][1]['mass_g']:.2f} g"
                for n in sorted(ticks)
            ],
            fontsize=7,
        )
        ax.set_xlabel("elements: space, total track, glass mass")
        ax.set_ylabel(name + " (test split)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{t['task']}, budget {t['budget']}, {len(t['seeds'])} seeds, exact optics", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
