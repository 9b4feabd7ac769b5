#!/usr/bin/env python3
"""Speed against accuracy of the optics model in the loop, at the task level (issue 20 item 3).

    python benches/optics_tradeoff.py --out runs/tradeoff [--task iq-software] [--budget quick]
                                      [--points all|optics] [--threads 2] [--bundle]

Each point is the end-to-end training of one run (Alg. 1, the budget's schedule, the same seed,
batches and noise) with one dial changed from the default (surrogate optics, 64 px patches,
all 13 field samples):
* optics: surrogate | exact | hybrid;
* the renderer's patch: 32 | 64 | 128 px (surrogate optics);
* the field samples K the renderer uses: 4 | 7 | 13 (surrogate optics).
Every trained camera is then evaluated the same way: on the run's held-out images under the
exact engine's PSFs of its final lens, all 13 fields, 32 px patches (the finest renderer), with
its own trained ISP; the paired 95 % bootstrap interval over images is against the default
point. The wall time is the training's (what the dial costs; the evaluation is the same for all).

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

import torch

POINTS = {  # name: (sweep, overrides)
    "surrogate": ("optics", {}),
    "exact": ("optics", {"optics": "exact"}),
    "hybrid": ("optics", {"optics": "hybrid"}),
    "patch32": ("patch", {"patch": 32}),
    "patch128": ("patch", {"patch": 128}),
    "fields4": ("fields", {"fields": 4}),
    "fields7": ("fields", {"fields": 7}),
}
EVAL_PATCH = 32


def run_point(name: str, overrides: dict, a, log) -> dict:
    from optix_e2e.camera import Camera, FixedOptics, calibrated_preset
    from optix_e2e.camera.stages import image_height_fractions
    from optix_e2e.optimize import evaluate as ev
    from optix_e2e.optimize.config import make_config
    from optix_e2e.optimize.hybrid import OpticsMonitor
    from optix_e2e.optimize.outputs import design_lens
    from optix_e2e.optimize.run import build_camera, load_surrogate, make_optimizer, train
    from optix_e2e.surrogate.exact import exact_optics
    from optix_e2e.surrogate.refine import RefineSettings
    from optix_e2e.tasks import SensorFrame, heldout_set
    from optix_e2e.tasks.scenes import POSITIONS

    out = Path(a.out) / name
    out.mkdir(parents=True, exist_ok=True)
    done = out / "point.json"
    if done.is_file():
        return json.loads(done.read_text())
    cfg = make_config(a.budget, task=a.task, threads=a.threads or None, **overrides)
    frame = SensorFrame()
    sur = load_surrogate(cfg.surrogate, calibrated_preset("imx249").pixel_um)
    camera = build_camera(cfg, sur, frame=frame, own_surrogate=cfg.optics == "hybrid")
    monitor = OpticsMonitor(camera.optics, cfg.optics, cfg.check_every, cfg.hybrid_threshold, cfg.refine,
                            RefineSettings(designs=cfg.refine_designs, steps=cfg.refine_steps, seed=cfg.seed), log=log)
    res = train(cfg, camera, make_optimizer(cfg, camera, cfg.optimizer), out, "end_to_end", progress=not a.quiet,
                log=log, monitor=monitor)
    values = camera.optics.values().detach()
    exact = exact_optics(sur, values.double().numpy()[None])
    heights = image_height_fractions(design_lens(sur.manifest, values.numpy(), exact["image_distance"][0]),
                                     sur.fields_deg)
    samples = heldout_set(cfg.eval_size, exact["psf"].shape[-1] // 2, cfg.eval_procedural, cfg.eval_level, frame,
                          positions=POSITIONS[cfg.eval_positions])
    t0 = time.perf_counter()
    fo = FixedOptics(exact["psf"][0], exact["vignetting"][0], heights, patch=EVAL_PATCH,
                     full_field_px=frame.full_field_px)
    rows = ev.evaluate(Camera(fo, camera.sensor, camera.isp), samples)
    summ = ev.summarize(rows)
    om = monitor.summary()
    point = {"name": name, "task": cfg.task, "budget": cfg.budget, "optics": cfg.optics, "patch": cfg.patch,
             "fields": cfg.fields or len(sur.fields_deg), "steps": res["steps"], "wall_s": res["wall_s"],
             "eval_s": time.perf_counter() - t0, "psnr_db": summ["psnr_db"], "ssim": summ["ssim"],
             "lpips": summ["lpips"], "haarpsi": summ["haarpsi"],
             "final_worst_field_error": max(om["final_error_per_field"]),
             "final_network_worst_field_error": max(om["final_network_error_per_field"]),
             "n_refinements": om["n_refinements"],
             "exact_gradient_steps": sum(h.get("optics") == "exact" and h["block"] in ("optics", "all")
                                         for h in res["history"]),
             "engine_designs": om["engine_designs"], "lens": [float(x) for x in values], "rows": rows,
             "checks": om["checks"], "events": om["events"]}
    done.write_text(json.dumps(point))
    return point


def main() -> None:
    from optix_e2e.optimize import evaluate as ev

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--task", default="iq-software")
    ap.add_argument("--budget", default="quick")
    ap.add_argument("--points", default="all", help="all, optics (the three optics models), or names, comma-separated")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--bundle", action="store_true", help="copy the CSV into the package (for --optics auto)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    names = (list(POINTS) if a.points == "all" else [n for n, (s, _) in POINTS.items() if s == "optics"]
             if a.points == "optics" else a.points.split(","))
    unknown = [n for n in names if n not in POINTS]
    if unknown:
        raise SystemExit(f"unknown point(s) {', '.join(unknown)}; known: {', '.join(POINTS)}")
    if "surrogate" not in names:
        names = ["surrogate", *names]  # the reference of the paired intervals
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    points = {}
    for n in names:
        print(f"== {n}", flush=True)
        points[n] = run_point(n, POINTS[n][1], a, lambda m: print(m, flush=True))
        p = points[n]
        print(f"   training {p['wall_s']:.0f} s, held-out PSNR {p['psnr_db']:.3f} dB, SSIM {p['ssim']:.4f} "
              f"(exact optics); surrogate worst-field error at the final design {p['final_network_worst_field_error']:.4f}",
              flush=True)
    ref = points["surrogate"]["rows"]
    table = []
    for n, p in points.items():
        pr = ev.paired(ref, p["rows"], 2000, 0)
        table.append({"task": p["task"], "budget": p["budget"], "sweep": POINTS[n][0], "point": n,
                      "optics": p["optics"], "patch": p["patch"], "fields": p["fields"], "steps": p["steps"],
                      "wall_s": round(p["wall_s"], 1), "psnr_db": round(p["psnr_db"], 4), "ssim": round(p["ssim"], 5),
                      "lpips": round(p["lpips"], 5), "haarpsi": round(p["haarpsi"], 5),
                      "psnr_vs_surrogate": round(pr["psnr_db"]["mean"], 4),
                      "psnr_vs_surrogate_lo": round(pr["psnr_db"]["ci95"][0], 4),
                      "psnr_vs_surrogate_hi": round(pr["psnr_db"]["ci95"][1], 4),
                      "final_worst_field_error": round(p["final_worst_field_error"], 5),
                      "final_network_worst_field_error": round(p["final_network_worst_field_error"], 5),
                      "n_refinements": p["n_refinements"], "exact_gradient_steps": p["exact_gradient_steps"]})
    # the default point appears in every sweep
    for sweep in ("patch", "fields"):
        if any(r["sweep"] == sweep for r in table):
            table.append({**next(r for r in table if r["point"] == "surrogate"), "sweep": sweep})
    with open(out / "tradeoff.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    (out / "tradeoff.json").write_text(json.dumps({"points": table, "eval_patch": EVAL_PATCH}, indent=1))
    chart(out / "tradeoff.png", table)
    print(f"wrote {out / 'tradeoff.csv'}, {out / 'tradeoff.png'}")
    if a.bundle:
        from optix_e2e.optimize.hybrid import tradeoff_path

        dest = Path(__file__).resolve().parent.parent / "python" / "optix_e2e" / "bundled" / tradeoff_path().name
        shutil.copyfile(out / "tradeoff.csv", dest)
        print(f"bundled: {dest}")


def chart(path: Path, table: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {"optics": "tab:blue", "patch": "tab:orange", "fields": "tab:green"}
    for ax, metric, label in ((axes[0], "psnr_db", "held-out PSNR (dB), exact optics"),
                              (axes[1], "ssim", "held-out SSIM, exact optics")):
        for sweep, c in colours.items():
            rows = sorted((r for r in table if r["sweep"] == sweep), key=lambda r: r["wall_s"])
            if not rows:
                continue
            ax.plot([r["wall_s"] for r in rows], [r[metric] for r in rows], "o-", color=c, label=sweep, alpha=0.8)
            for r in rows:
                ax.annotate(r["point"], (r["wall_s"], r[metric]), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_xlabel("training wall time (s)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(title="dial")
    fig.suptitle(f"{table[0]['task']}: the optics model in the loop, speed against task accuracy "
                 f"({table[0]['budget']} budget, one seed)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
