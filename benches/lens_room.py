#!/usr/bin/env python3
"""How much any lens could give a design run: its nominal baseline trained again behind an
ideal lens, on the same budget, and evaluated on the run's own held-out set.

    python benches/lens_room.py RUN_DIR [RUN_DIR ...] --out DIR [--lens perfect|sharp|delta] [--threads N]

RUN_DIR is a finished image-quality run (`optix design iq-software | iq-hardware | low-light`,
its eval_*_exact.json cache and nominal_state.pt present). The bench repeats the run's
nominal baseline with one change: the lens is ideal. The processing starts where the
baseline's started (the pre-trained software ISP, or the seeded hardware-ISP start), with the
same schedule and updates per block (build.make_optimizer "nominal"), batches (the run's
training images too) and sensor-noise draws (the run's seed). It is then evaluated on the
run's held-out samples with their noise draws, rebuilt and checked against the run's rows.

``--lens`` says which ideal lens:

* ``perfect`` (default): camera/stages.py PerfectOptics, every point images to a point, no
  vignetting, the renderer bypassed. A loose bound: it also escapes the nominal's shading
  (cos^4 falloff included) and the renderer's own resampling of each PSF to its azimuth.
* ``sharp``: no blur, the nominal's relative illumination (engine-computed, at each field),
  the renderer bypassed (SharpShadedOptics). Folders RUN_NAME-sharp.
* ``delta``: a one-pixel PSF and the nominal's relative illumination through the renderer
  (FixedOptics), as the simulator renders a lens that blurs nothing: the bound for a real
  lens in this simulator. Folders RUN_NAME-delta. Since issue 54 a design run trains and
  evaluates this one itself (results.json ``ideal_lens``, the same camera_design.build.delta_lens
  and budget): the bench repeats it for runs made before, and checks a newer run's figures.

So "ideal + fine-tuned minus nominal + fine-tuned" bounds what a lens can add to the
baseline under this processing and budget; "ideal + fine-tuned minus end-to-end" is what
the end-to-end camera leaves. Both are paired intervals over the held-out images (frame,
centre, corner: evaluate.paired_by_position); with several seeds of a task, Student's t
interval over the seeds too.

Writes DIR/RUN_NAME[-KIND]/{config.json, perfect_state.pt (resumable),
eval_perfect_finetuned.json} and DIR/lens_room[-KIND].{json,md} over the runs of the call. It
measures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from optix_e2e.camera import PerfectOptics
from optix_e2e.camera_design import eval_cache
from optix_e2e.camera_design import evaluate as ev
from optix_e2e.camera_design.build import build_camera, delta_lens, make_optimizer, nominal_shading, start_run
from optix_e2e.camera_design.config import DesignConfig, run_config
from optix_e2e.camera_design.training import train
from optix_e2e.errors import InputError
from optix_e2e.io import write_json_atomic
from optix_e2e.optics.render import shade
from optix_e2e.scenes import ImageFolder
from optix_e2e.scenes.corpus import PhotoCorpus
from optix_e2e.tasks import heldout_set
from optix_e2e.tasks.samples import POSITIONS
from optix_e2e.torchfile import load_plain

METRIC_NAMES = {"psnr_db": "PSNR (dB)", "ssim": "SSIM", "lpips": "LPIPS", "haarpsi": "HaarPSI"}


class SharpShadedOptics(PerfectOptics):
    """No blur, the given relative illumination [K, C] at field heights [K] (fractions of the
    full field): the renderer's shading step (optics/render.py) without its PSFs."""

    def __init__(self, psf_size: int, vignetting, fields, *, full_field_px: float):
        super().__init__(psf_size, full_field_px=full_field_px)
        self.register_buffer("vignetting", torch.as_tensor(vignetting, dtype=torch.float32))
        self.register_buffer("fields", torch.as_tensor(fields, dtype=torch.float32))

    def forward(self, image: torch.Tensor, offset_px=(0.0, 0.0)) -> torch.Tensor:
        return shade(image, self.vignetting, self.fields, self.full_field_px, offset_px)


def run_json(run: Path, name: str) -> dict:
    """A finished run's config.json or results.json; one line where it has none."""
    try:
        return json.loads((run / name).read_text())
    except (OSError, ValueError) as e:
        raise SystemExit(f"{run}: not a finished design run ({name}: {e})") from None


def cached_rows(run: Path, who: str) -> list[dict]:
    path = run / f"eval_{who}_exact.json"
    try:
        return json.loads(path.read_text())["rows"]
    except (OSError, ValueError, KeyError) as e:
        raise SystemExit(f"{run}: no held-out rows in {path.name} ({e}); run the design to its end first") from None


#: the ideal lens of each --lens kind: its folder suffix and its label in the tables
LENS_KINDS = {
    "perfect": ("", "no blur, no shading, the renderer bypassed"),
    "sharp": ("-sharp", "no blur, the nominal's shading, the renderer bypassed"),
    "delta": ("-delta", "a point PSF and the nominal's shading through the renderer"),
}


def held_out_matches(samples, rows: list[dict], full_field_px: float) -> bool:
    """The rebuilt samples are the run's: the same images, positions and crop radii, in order."""
    if len(samples) != len(rows):
        return False
    return all(
        (s.name, s.position) == (r["image"], r["position"])
        and abs(float(np.hypot(*s.offset_px)) / full_field_px - r["radius"]) <= 1e-9
        for s, r in zip(samples, rows)
    )


def ideal_lens(kind: str, sur, results: dict, window: int, cfg: DesignConfig, frame):
    """The lens that replaces the nominal in the baseline (``LENS_KINDS``)."""
    if kind == "perfect":
        return PerfectOptics(window, full_field_px=frame.full_field_px)
    nominal_values = np.asarray(results["design"]["nominal"], np.float64)
    if kind == "delta":  # the design run's own ideal lens (results.json ideal_lens): one definition
        lens = delta_lens(sur, nominal_values, patch=cfg.patch, full_field_px=frame.full_field_px)
        if lens.psf_size != window:
            raise SystemExit(f"the delta lens's window is {lens.psf_size} pixels, the run's {window}")
        return lens
    # the nominal's engine vignetting where its chief rays land (as the run's evaluation places them)
    vignetting, heights, _ = nominal_shading(sur, nominal_values)
    return SharpShadedOptics(window, vignetting, heights, full_field_px=frame.full_field_px)


def room(run: Path, out: Path, threads: int | None, progress: bool, kind: str = "perfect") -> dict:
    try:
        cfg = run_config(run).check()
    except InputError as err:
        raise SystemExit(str(err)) from None
    if cfg.task == "detection":
        raise SystemExit(f"{run}: a detection run; this bench is for the image-quality tasks")
    if threads is not None:
        cfg = DesignConfig(**{**cfg.to_json(), "threads": threads}).check()
    results = run_json(run, "results.json")
    window = int(results["exact_psf_energy_in_window"]["window_px"])
    trained_window = load_plain(run / "nominal_state.pt", "design checkpoint")["camera"]["optics.psf"].shape[-1]
    if trained_window != window:  # the camera's margin, so the training crops, follow the PSF window
        raise SystemExit(f"{run}: its baseline trained on {trained_window}-pixel PSFs, its evaluation on {window}")
    _, _, frame, sur = start_run(cfg, out)
    samples = heldout_set(
        cfg.eval_size,
        window // 2,
        cfg.eval_procedural,
        cfg.eval_level,
        frame,
        positions=POSITIONS[cfg.eval_positions],
    )
    nominal, e2e = cached_rows(run, "nominal"), cached_rows(run, "end_to_end")
    if not held_out_matches(samples, nominal, frame.full_field_px):
        raise SystemExit(f"{run}: the rebuilt held-out set is not the run's (another code version?)")
    settings = {"run": str(run.resolve()), "window_px": window, "lens": kind, **cfg.to_json()}
    made = json.loads((out / "config.json").read_text()) if (out / "config.json").is_file() else None
    if made is not None and made != settings:
        raise SystemExit(f"{out} was made for another run or settings; use another --out")
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "config.json", settings)
    lens = ideal_lens(kind, sur, results, window, cfg, frame)
    camera = build_camera(cfg, sur, fixed_optics=lens, frame=frame)
    opt = make_optimizer(cfg, camera, "nominal")
    log = print if progress else None
    folder = ImageFolder(cfg.images) if cfg.images else None  # the run's own training images
    corpus = PhotoCorpus(cfg.photos, "train") if cfg.photos else None  # the run's training photographs
    trained = train(
        cfg, camera, opt, out, "perfect", progress=progress, frame=frame, log=log, folder=folder, corpus=corpus
    )

    eval_path, code = out / "eval_perfect_finetuned.json", eval_cache.code_digest()
    try:
        cached = json.loads(eval_path.read_text())
        perfect = cached["rows"] if cached.get("code") == code else None
    except (OSError, ValueError, KeyError):
        perfect = None
    if perfect is None:
        perfect = ev.evaluate(camera, samples)
        write_json_atomic(eval_path, {"code": code, "rows": perfect})
    n_boot, seed = cfg.bootstrap, cfg.seed
    return {
        "run": str(run),
        "task": cfg.task,
        "seed": cfg.seed,
        "budget": cfg.budget,
        "lens": kind,
        "updates": trained["updates"],
        "train_wall_s": trained["wall_s"],
        "means": {
            "nominal": ev.summarize(nominal),
            "end_to_end": ev.summarize(e2e),
            "perfect_finetuned": ev.summarize(perfect),
            # what the run itself recorded (results.json): the nominal's processing behind a perfect
            # lens (runs made before issue 54), the run's own delta lens (runs made since)
            "perfect_nominal_processing": results.get("perfect_lens"),
            "run_ideal_lens": results.get("ideal_lens"),
        },
        # the most a lens could add to the baseline, and what the end-to-end camera leaves
        # ("perfect": the ideal lens of this --lens kind)
        "perfect_minus_nominal": ev.paired_by_position(nominal, perfect, n_boot, seed),
        "perfect_minus_end_to_end": ev.paired_by_position(e2e, perfect, n_boot, seed),
        "end_to_end_minus_nominal": ev.paired_by_position(nominal, e2e, n_boot, seed),
    }


def label(row: dict) -> str:
    kind = row.get("lens", "perfect")
    return "" if kind == "perfect" else f" ({LENS_KINDS[kind][1]})"


def table(rows: list[dict]) -> str:
    from alg1_vs_vanilla import seeds_interval

    def cell(d: dict) -> str:
        m = d["psnr_db"]
        return f"{m['mean']:+.2f} [{m['ci95'][0]:+.2f}, {m['ci95'][1]:+.2f}]"

    def corner(r: dict) -> str:
        d = r["perfect_minus_nominal"].get("corner")
        return cell(d) if d else "not evaluated"

    lines = [
        "| run | end-to-end minus nominal | ideal minus nominal (the lens's room) | ideal minus end-to-end | "
        "ideal minus nominal, corner |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        name = Path(r["run"]).name + label(r)
        lines.append(
            f"| {name} | {cell(r['end_to_end_minus_nominal']['frame'])} | {cell(r['perfect_minus_nominal']['frame'])} "
            f"| {cell(r['perfect_minus_end_to_end']['frame'])} | {corner(r)} |"
        )
    by_task: dict[str, list[dict]] = {}
    for r in rows:
        by_task.setdefault(r["task"] + label(r), []).append(r)
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


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: the run's)")
    ap.add_argument(
        "--lens",
        choices=tuple(LENS_KINDS),
        default="perfect",
        help="the ideal lens: " + "; ".join(f"{k}: {v[1]}" for k, v in LENS_KINDS.items()),
    )
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for run in args.runs:
        print(f"== {run}", flush=True)
        suffix = LENS_KINDS[args.lens][0]
        rows.append(room(run, args.out / (run.name + suffix), args.threads, not args.quiet, args.lens))
        r = rows[-1]["perfect_minus_nominal"]["frame"]["psnr_db"]
        print(
            f"   ideal ({args.lens}) + fine-tuned minus nominal + fine-tuned: {r['mean']:+.2f} dB {np.round(r['ci95'], 2)}"
        )
        stem = "lens_room" + LENS_KINDS[args.lens][0]
        write_json_atomic(args.out / f"{stem}.json", rows)
        (args.out / f"{stem}.md").write_text(table(rows))


if __name__ == "__main__":
    main()
