#!/usr/bin/env python3
"""Speed against accuracy of the optics model in the loop, at the task level (issue 20 item 3).

    python benches/optics_tradeoff.py --out runs/tradeoff [--task iq-software] [--budget quick]
                                      [--points all|optics] [--threads 2] [--bundle]

Each point is the end-to-end training of runs (Alg. 1, the budget's schedule; per seed the same
batches and noise for every point) with one dial changed from the reference point (surrogate optics, 64 px patches,
all 13 field samples):
* optics: surrogate | exact | hybrid (refined by the additive correction) | hybrid_network
  (refined by fine-tuning the network on engine designs about the current one);
* the renderer's patch: 32 | 64 | 128 px (surrogate optics);
* the field samples K the renderer uses: 4 | 7 | 13 (surrogate optics).
Every trained camera is then evaluated the same way: on the run's held-out images under the
exact engine's PSFs of its final lens, all 13 fields, 32 px patches (the finest renderer), with
its own trained ISP; paired 95 % bootstrap intervals over images against the reference point and
against the best point of the sweep; with several seeds (--seeds 0,1,2) a point's rows are pooled
(per image: the mean over seeds and positions). The wall time is the training's (what the dial costs; the evaluation is the same for all).

Writes OUT/tradeoff.csv, OUT/tradeoff.json and OUT/tradeoff.png (held-out PSNR and SSIM
against training wall time). Every point resumes from OUT/<point>/ if interrupted. --bundle
copies the CSV into the package (python/optix_e2e/bundled/optics_tradeoff.csv), where
`optix design --optics auto` reads it. It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import time
from pathlib import Path

import numpy as np
import torch

POINTS = {  # name: (sweep, overrides)
    "surrogate": ("optics", {"optics": "surrogate"}),
    "exact": ("optics", {"optics": "exact"}),
    "hybrid": ("optics", {"optics": "hybrid"}),
    "hybrid_network": ("optics", {"optics": "hybrid", "refine": "network"}),
    "patch32": ("patch", {"patch": 32, "optics": "surrogate"}),
    "patch128": ("patch", {"patch": 128, "optics": "surrogate"}),
    "fields4": ("fields", {"fields": 4, "optics": "surrogate"}),
    "fields7": ("fields", {"fields": 7, "optics": "surrogate"}),
}
EVAL_PATCH = 32


def run_point(name: str, seed: int, overrides: dict, a, log) -> dict:
    from optix_e2e.camera import Camera, FixedOptics, calibrated_preset
    from optix_e2e.camera_design import evaluate as ev
    from optix_e2e.camera_design.build import build_camera, design_field_heights, load_surrogate, make_optimizer
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.camera_design.hybrid import OpticsMonitor, exact_gradient_steps
    from optix_e2e.camera_design.training import train
    from optix_e2e.surrogate.ground_truth import exact_optics
    from optix_e2e.surrogate.refine import RefineSettings
    from optix_e2e.tasks import SensorFrame, heldout_set
    from optix_e2e.tasks.samples import POSITIONS

    out = Path(a.out) / (name if seed == 0 else f"{name}-s{seed}")
    out.mkdir(parents=True, exist_ok=True)
    done = out / "point.json"
    if done.is_file():
        return json.loads(done.read_text())
    cfg = make_config(a.budget, task=a.task, threads=a.threads or None, seed=seed, **overrides)
    frame = SensorFrame()
    sur = load_surrogate(cfg.surrogate, calibrated_preset("imx249").pixel_um)
    camera = build_camera(cfg, sur, frame=frame, own_surrogate=cfg.optics == "hybrid")
    monitor = OpticsMonitor(
        camera.optics,
        cfg.optics,
        cfg.check_every,
        cfg.hybrid_threshold,
        cfg.refine,
        RefineSettings(designs=cfg.refine_designs, steps=cfg.refine_steps, seed=cfg.seed),
        log=log,
    )
    res = train(
        cfg,
        camera,
        make_optimizer(cfg, camera, cfg.optimizer),
        out,
        "end_to_end",
        progress=not a.quiet,
        log=log,
        monitor=monitor,
    )
    values = camera.optics.values().detach()
    exact = exact_optics(sur, values.double().numpy()[None])
    heights = design_field_heights(sur, values.numpy(), exact["image_distance"][0])
    samples = heldout_set(
        cfg.eval_size,
        exact["psf"].shape[-1] // 2,
        cfg.eval_procedural,
        cfg.eval_level,
        frame,
        positions=POSITIONS[cfg.eval_positions],
    )
    t0 = time.perf_counter()
    fo = FixedOptics(
        exact["psf"][0], exact["vignetting"][0], heights, patch=EVAL_PATCH, full_field_px=frame.full_field_px
    )
    rows = ev.evaluate(Camera(fo, camera.sensor, camera.isp), samples)
    summ = ev.summarize(rows)
    om = monitor.summary()
    point = {
        "name": name,
        "task": cfg.task,
        "budget": cfg.budget,
        "optics": cfg.optics,
        "refine": cfg.refine if cfg.optics == "hybrid" else "",
        "patch": cfg.patch,
        "fields": cfg.fields or len(sur.fields_deg),
        "steps": res["steps"],
        "wall_s": res["wall_s"],
        "eval_s": time.perf_counter() - t0,
        "psnr_db": summ["psnr_db"],
        "ssim": summ["ssim"],
        "lpips": summ["lpips"],
        "haarpsi": summ["haarpsi"],
        "final_worst_field_error": max(om["final_error_per_field"]),
        "final_network_worst_field_error": max(om["final_network_error_per_field"]),
        "n_refinements": om["n_refinements"],
        "exact_gradient_steps": exact_gradient_steps(res["history"]),
        "engine_designs": om["engine_designs"],
        "lens": [float(x) for x in values],
        "rows": rows,
        "checks": om["checks"],
        "events": om["events"],
    }
    done.write_text(json.dumps(point))
    return point


def main() -> None:
    from optix_e2e.camera_design import evaluate as ev

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--budget", default="quick")
    ap.add_argument(
        "--points",
        default="all",
        help="all, optics (the optics models), or names, comma-separated; NAME@0+1 runs that point "
        "with those seeds only",
    )
    ap.add_argument("--seeds", default="0", help="seeds of every point, comma-separated (default 0)")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--bundle", action="store_true", help="copy the CSV into the package (for --optics auto)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    seeds = [int(x) for x in a.seeds.split(",")]
    specs = (
        list(POINTS)
        if a.points == "all"
        else [n for n, (s, _) in POINTS.items() if s == "optics"]
        if a.points == "optics"
        else a.points.split(",")
    )
    plan = {}
    for spec in specs:
        name, _, own = spec.partition("@")
        plan[name] = [int(x) for x in own.split("+")] if own else seeds
    unknown = [n for n in plan if n not in POINTS]
    if unknown:
        raise SystemExit(f"unknown point(s) {', '.join(unknown)}; known: {', '.join(POINTS)}")
    if "surrogate" not in plan:
        plan = {"surrogate": seeds, **plan}  # the reference of the paired intervals
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    runs: dict[str, list[dict]] = {}
    for n, ss in plan.items():
        for seed in ss:
            print(f"== {n}, seed {seed}", flush=True)
            p = run_point(n, seed, POINTS[n][1], a, lambda m: print(m, flush=True))
            runs.setdefault(n, []).append(p)
            print(
                f"   training {p['wall_s']:.0f} s, held-out PSNR {p['psnr_db']:.3f} dB, SSIM {p['ssim']:.4f} "
                f"(exact optics); surrogate worst-field error at the final design "
                f"{p['final_network_worst_field_error']:.4f}",
                flush=True,
            )
    # a point's figures: over its seeds; its rows pooled (per image: the mean over seeds and positions)
    rows_of = {n: [r for p in ps for r in p["rows"]] for n, ps in runs.items()}
    table = []
    for n, ps in runs.items():
        summ = ev.summarize(rows_of[n])
        pr = ev.paired(rows_of["surrogate"], rows_of[n], 2000, 0)
        mean = lambda k: float(np.mean([p[k] for p in ps]))  # noqa: E731
        table.append(
            {
                "task": ps[0]["task"],
                "budget": ps[0]["budget"],
                "sweep": POINTS[n][0],
                "point": n,
                "optics": ps[0]["optics"],
                "refine": ps[0].get("refine", ""),
                "patch": ps[0]["patch"],
                "fields": ps[0]["fields"],
                "steps": ps[0]["steps"],
                "seeds": len(ps),
                "wall_s": round(mean("wall_s"), 1),
                "psnr_db": round(summ["psnr_db"], 4),
                "ssim": round(summ["ssim"], 5),
                "lpips": round(summ["lpips"], 5),
                "haarpsi": round(summ["haarpsi"], 5),
                "psnr_per_seed": ";".join(f"{p['psnr_db']:.3f}" for p in ps),
                "psnr_vs_surrogate": round(pr["psnr_db"]["mean"], 4),
                "psnr_vs_surrogate_lo": round(pr["psnr_db"]["ci95"][0], 4),
                "psnr_vs_surrogate_hi": round(pr["psnr_db"]["ci95"][1], 4),
                "final_worst_field_error": round(mean("final_worst_field_error"), 5),
                "final_network_worst_field_error": round(mean("final_network_worst_field_error"), 5),
                "n_refinements": mean("n_refinements"),
                "exact_gradient_steps": mean("exact_gradient_steps"),
                "engine_designs": mean("engine_designs"),
            }
        )
    # the reference point (surrogate) appears in every sweep
    for sweep in ("patch", "fields"):
        if any(r["sweep"] == sweep for r in table):
            table.append({**next(r for r in table if r["point"] == "surrogate"), "sweep": sweep})
    # each point against the best of its sweep (paired over the same images): what --optics auto reads
    for sweep in {r["sweep"] for r in table}:
        rows = [r for r in table if r["sweep"] == sweep]
        best = max(rows, key=lambda r: r["psnr_db"])
        for r in rows:
            pr = ev.paired(rows_of[best["point"]], rows_of[r["point"]], 2000, 0)["psnr_db"]
            r.update(
                {
                    "best_in_sweep": best["point"],
                    "psnr_vs_best": round(pr["mean"], 4),
                    "psnr_vs_best_lo": round(pr["ci95"][0], 4),
                    "psnr_vs_best_hi": round(pr["ci95"][1], 4),
                }
            )
    with open(out / "tradeoff.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    # the final design's PSF error per field (median over channels), mean over seeds: of the model the
    # last steps used, and of the plain network
    final_fields = {}
    for n, ps in runs.items():
        if POINTS[n][0] != "optics":
            continue
        last = [p["checks"][-1] for p in ps]
        final_fields[n] = {
            k: [float(x) for x in np.mean([c[k] for c in last], axis=0)]
            for k in ("error_per_field", "network_error_per_field")
        }
        final_fields[n]["last_steps_on"] = [c["backend"] for c in last]
        print(
            f"{n}: final design, worst field: model used {max(final_fields[n]['error_per_field']):.4f}, network "
            f"{max(final_fields[n]['network_error_per_field']):.4f}; per field (network) "
            + " ".join(f"{x:.3f}" for x in final_fields[n]["network_error_per_field"])
        )
    (out / "tradeoff.json").write_text(
        json.dumps(
            {
                "points": table,
                "eval_patch": EVAL_PATCH,
                "final_error_per_field": final_fields,
                "runs": {n: [{k: v for k, v in p.items() if k != "rows"} for p in ps] for n, ps in runs.items()},
            },
            indent=1,
        )
    )
    chart(out / "tradeoff.png", table)
    print(f"wrote {out / 'tradeoff.csv'}, {out / 'tradeoff.json'}, {out / 'tradeoff.png'}")
    if a.bundle:
        from optix_e2e.camera_design.hybrid import tradeoff_path

        dest = Path(__file__).resolve().parent.parent / "python" / "optix_e2e" / "bundled" / tradeoff_path().name
        shutil.copyfile(out / "tradeoff.csv", dest)
        print(f"bundled: {dest}")


def chart(path: Path, table: list[dict]) -> None:
    """Held-out PSNR and SSIM (exact optics) against training time, one marker per point; the
    PSNR panel's bars: the paired 95 % interval against the reference (surrogate) point, drawn
    about the reference point's value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    colours = {"optics": "tab:blue", "patch": "tab:orange", "fields": "tab:green"}
    ref = next(r for r in table if r["point"] == "surrogate")
    seen = set()
    for r in table:
        if r["point"] in seen:
            continue
        seen.add(r["point"])
        c = "black" if r["point"] == "surrogate" else colours[r["sweep"]]
        label = r["point"] + ("" if r["seeds"] == ref["seeds"] else f" ({r['seeds']} seed)")
        lo = ref["psnr_db"] + r["psnr_vs_surrogate_lo"]
        hi = ref["psnr_db"] + r["psnr_vs_surrogate_hi"]
        mid = ref["psnr_db"] + r["psnr_vs_surrogate"]
        axes[0].errorbar([r["wall_s"]], [mid], yerr=[[mid - lo], [hi - mid]], fmt="o", color=c, capsize=3)
        axes[1].plot([r["wall_s"]], [r["ssim"]], "o", color=c)
        for ax, y in ((axes[0], mid), (axes[1], r["ssim"])):
            ax.annotate(label, (r["wall_s"], y), textcoords="offset points", xytext=(5, 3), fontsize=8)
    axes[0].set_ylabel("held-out PSNR (dB), exact optics\n(bars: paired 95 % interval vs surrogate)")
    axes[1].set_ylabel("held-out SSIM, exact optics")
    for ax in axes:
        ax.set_xlabel("training wall time (s)")
        ax.grid(alpha=0.3)
    handles = [
        plt.Line2D([], [], marker="o", ls="", color=c, label=k)
        for k, c in (("reference (surrogate, 64 px, K = 13)", "black"), *((f"{k} dial", v) for k, v in colours.items()))
    ]
    axes[1].legend(handles=handles, fontsize=8)
    fig.suptitle(
        f"{table[0]['task']}: the optics model in the loop, speed against task accuracy "
        f"({table[0]['budget']} budget, {ref['seeds']} seeds per point unless marked)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
