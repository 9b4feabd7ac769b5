#!/usr/bin/env python3
"""Alg. 1 against vanilla Adam (paper Sec. 6.3, Fig. 12): the same task, initialization, seed
and number of steps, over several seeds.

    python benches/alg1_vs_vanilla.py --task iq-software --seeds 0 1 2 --budget full --out runs/fig12
                                      [--init uniform|nominal] [--config FILE.toml]

Runs `optix design` for each (optimizer, seed) (resumable: run it again to continue; a run
with its results.json is not run again), then writes OUT/fig12-TASK-INIT.csv (one row per run:
held-out PSNR / SSIM / LPIPS / HaarPSI under exact optics, final training loss, wall time, lens
steps cut back, and the PSNR against the run's own nominal + fine-tuned processing with its
interval at each evaluated position: did a random start reach the nominal camera?),
OUT/fig12-TASK-INIT.json (Alg. 1 minus vanilla per seed with its 95 % bootstrap interval over
the held-out images; the mean over seeds with two intervals: `seeds_ci95`, Student's t over
the per-seed differences, which counts how much a training run varies from seed to seed (the
interval to quote; wide with few seeds), and `pooled_ci95_given_runs`, a bootstrap over images
of their seed-averaged differences, which takes these trained runs as fixed and so only says
how sure the held-out set makes us about them) and
OUT/fig12-TASK-INIT.png (training loss against step, both optimizers, every seed); several
tasks can share one OUT. Each run trains its own nominal baseline: it gets the processing
updates its optimizer gives the end-to-end camera (Alg. 1's schedule without the optics block,
or vanilla over the processing), so the two optimizers' baselines differ. The
paper initializes the optics uniformly at random (--init uniform, the default here).
It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from optix_e2e.camera_design.evaluate import METRICS, paired


def run_config(user_toml: str | None, init: str) -> str:
    """The settings file every run of the comparison gets: the user's, with its relative paths
    made absolute (the copy lives in OUT) and ``optics_init`` set to ``init`` (a file that sets
    another is refused rather than silently mislabelled)."""
    import tomli_w

    from optix_e2e.camera_design.config import read_config_file

    data = read_config_file(Path(user_toml)) if user_toml else {}
    if data.setdefault("optics_init", init) != init:
        sys.exit(f"{user_toml}: optics_init = {data['optics_init']!r}, but --init {init}; say it once")
    return tomli_w.dumps(data)


def seeds_interval(d: list[float], level: float = 0.95) -> list[float] | None:
    """Student's t interval of the mean of per-seed differences (None with fewer than 2 seeds)."""
    from scipy import stats

    if len(d) < 2:
        return None
    m, se = float(np.mean(d)), float(np.std(d, ddof=1)) / np.sqrt(len(d))
    h = float(stats.t.ppf(0.5 + level / 2, len(d) - 1)) * se
    return [float(m - h), float(m + h)]


def vs_nominal(res: dict) -> dict:
    """The run's end-to-end camera against its own nominal + fine-tuned processing: PSNR
    difference and 95 % interval over images at each evaluated position (the headline first),
    so a random start's run says whether it reached the nominal camera."""
    out = {"nominal_psnr_db": res["nominal"]["psnr_db"]}
    by = res.get("paired_by_position") or {res.get("headline_position", "headline"): res["paired"]}
    for pos, pr in by.items():
        lo, hi = pr["psnr_db"]["ci95"]
        out.update({f"vs_nominal_psnr_db_{pos}": pr["psnr_db"]["mean"], f"ci95_lo_{pos}": lo, f"ci95_hi_{pos}": hi})
    return out


def held_out_rows(run: Path) -> list[dict]:
    """The end-to-end camera's held-out samples under exact optics, from the run's metrics.csv."""
    with open(run / "metrics.csv") as f:
        return [
            {**r, "radius": float(r["radius"]), **{m: float(r[m]) for m in METRICS}}
            for r in csv.DictReader(f)
            if r["camera"] == "end_to_end" and r["optics"] == "exact"
        ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--budget", default="full")
    ap.add_argument("--init", default="uniform", choices=["uniform", "nominal"])
    ap.add_argument("--config", default=None)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = out / f"{a.task}-{a.init}.toml"
    cfg.write_text(run_config(a.config, a.init))
    rows, curves = [], {}
    for seed in a.seeds:
        for opt in ("alg1", "vanilla"):
            run = out / f"{a.task}-{opt}-seed{seed}"
            cmd = [
                sys.executable,
                "-m",
                "optix_e2e",
                "design",
                a.task,
                "--out",
                str(run),
                "--budget",
                a.budget,
                "--optimizer",
                opt,
                "--seed",
                str(seed),
                "--config",
                str(cfg),
            ]
            if (run / "results.json").is_file():
                print(f"{run}: finished already", flush=True)
            else:
                print(" ".join(cmd), flush=True)
                subprocess.run(cmd, check=True)
            res = json.loads((run / "results.json").read_text())
            rows.append(
                {
                    "task": a.task,
                    "optimizer": opt,
                    "seed": seed,
                    **{m: res["end_to_end"][m] for m in METRICS},
                    "final_train_loss": res["training"]["end_to_end"]["final_loss"],
                    "wall_s": res["training"]["end_to_end"]["wall_s"],
                    "lens_steps": res["training"]["end_to_end"].get("lens_steps"),
                    "cut_steps": res["training"]["end_to_end"].get("cut_steps"),
                    **vs_nominal(res),
                }
            )
            with open(run / "history.csv") as f:
                curves[(opt, seed)] = [
                    (int(r["step"]), float(r["loss"])) for r in csv.DictReader(f) if r["run"] == "end_to_end"
                ]
    stem = f"fig12-{a.task}-{a.init}"
    with open(out / f"{stem}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    by = {(r["optimizer"], r["seed"]): r for r in rows}
    diffs = {m: [by[("alg1", s)][m] - by[("vanilla", s)][m] for s in a.seeds] for m in METRICS}
    # paired over held-out images (exact optics): per seed, and pooled (each image's
    # difference averaged over seeds and positions, then bootstrapped over images)
    held = {(opt, s): held_out_rows(out / f"{a.task}-{opt}-seed{s}") for s in a.seeds for opt in ("alg1", "vanilla")}
    per_seed_ci = {s: paired(held[("vanilla", s)], held[("alg1", s)]) for s in a.seeds}
    pooled = paired([r for s in a.seeds for r in held[("vanilla", s)]], [r for s in a.seeds for r in held[("alg1", s)]])
    summary = {
        "task": a.task,
        "budget": a.budget,
        "init": a.init,
        "seeds": a.seeds,
        "alg1_minus_vanilla": {
            m: {
                "per_seed": d,
                "mean": float(np.mean(d)),
                "seeds_ci95": seeds_interval(d),
                "seeds_alg1_better": int(sum((x < 0) if m == "lpips" else (x > 0) for x in d)),
                "per_seed_ci95": [per_seed_ci[s][m]["ci95"] for s in a.seeds],
                "pooled_ci95_given_runs": pooled[m]["ci95"],
            }
            for m, d in diffs.items()
        },
    }
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=2))
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for (opt, seed), c in sorted(curves.items()):
        steps, loss = zip(*c)
        k = max(1, len(loss) // 50)
        smooth = np.convolve(loss, np.ones(k) / k, mode="valid")
        ax.plot(
            steps[k - 1 :],
            smooth,
            color="C0" if opt == "alg1" else "C3",
            alpha=0.8,
            label=f"{opt}" if seed == a.seeds[0] else None,
        )
    ax.set_xlabel("step")
    ax.set_ylabel("training loss (L1 + w LPIPS)")
    ax.set_title(f"{a.task}: Alg. 1 vs vanilla, {len(a.seeds)} seeds, same init and steps")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / f"{stem}.png")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
