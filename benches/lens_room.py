#!/usr/bin/env python3
"""How much any lens could give a design run: its nominal baseline trained again behind a
perfect lens, on the same budget, and evaluated on the run's own held-out set.

    python benches/lens_room.py RUN_DIR [RUN_DIR ...] --out DIR [--threads N]

RUN_DIR is a finished image-quality run (`optix design iq-software | iq-hardware | low-light`,
its eval_*_exact.json cache present). The bench repeats the run's nominal baseline with one
change: the lens is perfect (camera/stages.py PerfectOptics: every point images to a point, no
vignetting). The processing starts where the baseline's started (the pre-trained software ISP,
or the seeded hardware-ISP start), with the same schedule and updates per block
(build.make_optimizer "nominal"), batches and sensor-noise draws (the run's seed). It is then
evaluated on the run's held-out samples with their noise draws, rebuilt and checked against
the run's cached rows.

``--shading nominal`` keeps the nominal lens's relative illumination (its engine-computed
vignetting, cos^4 falloff included, at each field) and removes only the blur: a sharp lens
that shades as the nominal does. Its folders are named RUN_NAME-shaded.

So "perfect + fine-tuned minus nominal + fine-tuned" bounds what a lens can add to the
baseline under this processing and budget; "perfect + fine-tuned minus end-to-end" is what
the end-to-end camera leaves. Both are paired intervals over the held-out images (frame, centre,
corner: evaluate.paired_by_position).

Writes DIR/RUN_NAME/{config.json, perfect_state.pt (resumable), eval_perfect_finetuned.json}
and DIR/lens_room.{json,md} (lens_room-shaded.* with --shading nominal). It measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from optix_e2e.camera import PerfectOptics
from optix_e2e.camera_design import evaluate as ev
from optix_e2e.camera_design.build import build_camera, design_field_heights, make_optimizer, start_run
from optix_e2e.camera_design.config import DesignConfig
from optix_e2e.camera_design.training import train
from optix_e2e.io import write_json_atomic
from optix_e2e.optics.render import interpolate_fields, pixel_polar
from optix_e2e.surrogate.ground_truth import exact_optics
from optix_e2e.tasks import heldout_set
from optix_e2e.tasks.samples import POSITIONS

METRIC_NAMES = {"psnr_db": "PSNR (dB)", "ssim": "SSIM", "lpips": "LPIPS", "haarpsi": "HaarPSI"}


class SharpShadedOptics(PerfectOptics):
    """No blur, the given relative illumination [K, C] at field heights [K] (fractions of the
    full field): the renderer's shading step (optics/render.py) without its PSFs."""

    def __init__(self, psf_size: int, vignetting, fields, *, full_field_px: float):
        super().__init__(psf_size, full_field_px=full_field_px)
        self.register_buffer("vignetting", torch.as_tensor(vignetting, dtype=torch.float32))
        self.register_buffer("fields", torch.as_tensor(fields, dtype=torch.float32))

    def forward(self, image: torch.Tensor, offset_px=(0.0, 0.0)) -> torch.Tensor:
        _, c, h, w = image.shape
        r, _ = pixel_polar(h, w, self.full_field_px, device=image.device, dtype=image.dtype, offset_px=offset_px)
        shade = interpolate_fields(self.vignetting.to(image), self.fields.to(image), r.reshape(-1))
        return image * shade.T.reshape(1, c, h, w)


def cached_rows(run: Path, who: str) -> list[dict]:
    path = run / f"eval_{who}_exact.json"
    try:
        return json.loads(path.read_text())["rows"]
    except (OSError, ValueError, KeyError) as e:
        raise SystemExit(f"{run}: no held-out rows in {path.name} ({e}); run the design to its end first") from None


def room(run: Path, out: Path, threads: int | None, progress: bool, shading: str = "none") -> dict:
    cfg = DesignConfig(**json.loads((run / "config.json").read_text())).check()
    if cfg.task == "detection":
        raise SystemExit(f"{run}: a detection run; this bench is for the image-quality tasks")
    if threads is not None:
        cfg = DesignConfig(**{**cfg.to_json(), "threads": threads}).check()
    results = json.loads((run / "results.json").read_text())
    window = int(results["exact_psf_energy_in_window"]["window_px"])
    _, _, frame, sur = start_run(cfg, out)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "config.json", {"run": str(run), "window_px": window, "shading": shading, **cfg.to_json()})
    if shading == "nominal":  # the nominal's engine vignetting where its chief rays land
        nominal_values = np.asarray(results["design"]["nominal"], np.float64)
        exact = exact_optics(sur, nominal_values[None])
        heights = design_field_heights(sur, nominal_values, float(exact["image_distance"][0]))
        lens = SharpShadedOptics(window, exact["vignetting"][0], heights, full_field_px=frame.full_field_px)
    else:
        lens = PerfectOptics(window, full_field_px=frame.full_field_px)
    camera = build_camera(cfg, sur, fixed_optics=lens, frame=frame)
    opt = make_optimizer(cfg, camera, "nominal")
    log = print if progress else None
    trained = train(cfg, camera, opt, out, "perfect", progress=progress, frame=frame, log=log)

    samples = heldout_set(
        cfg.eval_size,
        window // 2,
        cfg.eval_procedural,
        cfg.eval_level,
        frame,
        positions=POSITIONS[cfg.eval_positions],
    )
    nominal, e2e = cached_rows(run, "nominal"), cached_rows(run, "end_to_end")
    if [(s.name, s.position) for s in samples] != [(r["image"], r["position"]) for r in nominal]:
        raise SystemExit(f"{run}: the rebuilt held-out set is not the run's (another code version?)")
    eval_path = out / "eval_perfect_finetuned.json"
    try:
        perfect = json.loads(eval_path.read_text())["rows"]
    except (OSError, ValueError, KeyError):
        perfect = ev.evaluate(camera, samples)
        write_json_atomic(eval_path, {"rows": perfect})
    n_boot, seed = cfg.bootstrap, cfg.seed
    return {
        "run": str(run),
        "task": cfg.task,
        "seed": cfg.seed,
        "budget": cfg.budget,
        "shading": shading,
        "updates": trained["updates"],
        "train_wall_s": trained["wall_s"],
        "means": {
            "nominal": ev.summarize(nominal),
            "end_to_end": ev.summarize(e2e),
            "perfect_finetuned": ev.summarize(perfect),
            "perfect_nominal_processing": results.get("perfect_lens"),
        },
        # the most a lens could add to the baseline, and what the end-to-end camera leaves
        "perfect_minus_nominal": ev.paired_by_position(nominal, perfect, n_boot, seed),
        "perfect_minus_end_to_end": ev.paired_by_position(e2e, perfect, n_boot, seed),
        "end_to_end_minus_nominal": ev.paired_by_position(nominal, e2e, n_boot, seed),
    }


def table(rows: list[dict]) -> str:
    def cell(d: dict) -> str:
        m = d["psnr_db"]
        return f"{m['mean']:+.2f} [{m['ci95'][0]:+.2f}, {m['ci95'][1]:+.2f}]"

    def corner(r: dict) -> str:
        d = r["perfect_minus_nominal"].get("corner")
        return cell(d) if d else "not evaluated"

    lines = [
        "| run | end-to-end minus nominal | perfect minus nominal (the lens's room) | perfect minus end-to-end | "
        "perfect, corner minus nominal |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        name = Path(r["run"]).name + (" (the nominal's shading)" if r.get("shading") == "nominal" else "")
        lines.append(
            f"| {name} | {cell(r['end_to_end_minus_nominal']['frame'])} | {cell(r['perfect_minus_nominal']['frame'])} "
            f"| {cell(r['perfect_minus_end_to_end']['frame'])} | {corner(r)} |"
        )
    by_task: dict[str, list[dict]] = {}
    for r in rows:
        by_task.setdefault(
            r["task"] + (" (the nominal's shading)" if r.get("shading") == "nominal" else ""), []
        ).append(r)
    for task, rs in by_task.items():
        if len(rs) < 2:
            continue
        cells = []
        for key in ("end_to_end_minus_nominal", "perfect_minus_nominal", "perfect_minus_end_to_end"):
            d = [r[key]["frame"]["psnr_db"]["mean"] for r in rs]
            lo, hi = seeds_interval(d)
            cells.append(f"**{np.mean(d):+.2f}** [{lo:+.2f}, {hi:+.2f}]")
        lines.append(f"| {task}, mean of {len(rs)} seeds (t interval over seeds) | " + " | ".join(cells) + " | |")
    return (
        "\n".join(lines) + "\n\nFrame PSNR in dB unless marked; paired 95 % bootstrap intervals over held-out images.\n"
    )


def seeds_interval(d: list[float], level: float = 0.95) -> tuple[float, float]:
    """Student's t interval of the mean of per-seed values (at least 2)."""
    from scipy import stats

    m, se = float(np.mean(d)), float(np.std(d, ddof=1)) / np.sqrt(len(d))
    h = float(stats.t.ppf(0.5 + level / 2, len(d) - 1)) * se
    return m - h, m + h


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: the run's)")
    ap.add_argument(
        "--shading", choices=("none", "nominal"), default="none", help="the sharp lens's relative illumination"
    )
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for run in args.runs:
        print(f"== {run}", flush=True)
        name = run.name + ("-shaded" if args.shading == "nominal" else "")
        rows.append(room(run, args.out / name, args.threads, not args.quiet, args.shading))
        r = rows[-1]["perfect_minus_nominal"]["frame"]["psnr_db"]
        print(f"   perfect + fine-tuned minus nominal + fine-tuned: {r['mean']:+.2f} dB {np.round(r['ci95'], 2)}")
        stem = "lens_room" + ("-shaded" if args.shading == "nominal" else "")
        write_json_atomic(args.out / f"{stem}.json", rows)
        (args.out / f"{stem}.md").write_text(table(rows))


if __name__ == "__main__":
    main()
