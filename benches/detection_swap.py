#!/usr/bin/env python3
"""Is a detection run's gain the lens or the training? Cross lenses with processing + detector
on the run's held-out street scenes, under the engine's exact PSFs (issue 35).

    python benches/detection_swap.py RUN [RUN_B] --out DIR [--blur-um S] [--recheck] [--threads N]

RUN is a finished `optix design detection` run; RUN_B (optional) another one on the same
held-out scenes and nominal lens, e.g. the vanilla run of the same seed. The lenses are the
nominal and each run's end-to-end lens (each at its own f-number); the "processing" of a
camera is its hardware ISP (through the reference ISP at its hyperparameters, as the run
evaluates) with its detector, and the sensor: the run's nominal baseline's and each run's
end-to-end camera's. Every lens is evaluated behind every processing; the diagonal is the
runs' own cameras: their saved detections are reused where the design run's own cache key
matches (the code, sensor, lens, processing and scenes), else evaluated again; every cell
this bench evaluates is kept under the same kind of key in DIR/cells/, so a second call (a
lens added) evaluates only what is new. ``--blur-um S`` adds a control lens, the nominal's PSFs
blurred by a Gaussian of S um (the same light). The bench evaluates on the CPU at fp32 and
refuses runs made otherwise. It reports mAP@0.5, mAP and dark-object mAP@0.5 of each cell, and paired
differences with 95 % bootstrap intervals over scenes (the run's own bootstrap settings):

* the lens's effect with the processing held: each end-to-end lens against the nominal
  lens, and end-to-end lens A against B, behind each processing;
* the processing's effect with the lens held;
* the whole cameras: each end-to-end camera against the nominal one, and A against B.

Writes DIR/detection_swap.json and DIR/detection_swap.md. It measures; it asserts nothing.

    python benches/detection_swap.py --seeds SWAP_DIR ... --out DIR

tabulates finished swaps of several seeds (the same effects in each): every effect per seed,
its mean and Student's t interval over seeds -> DIR/swap_seeds.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import torch

from optix_e2e.camera import FixedOptics
from optix_e2e.camera_design import eval_cache
from optix_e2e.camera_design.build import design_field_heights, start_run
from optix_e2e.camera_design.config import DesignConfig, run_config
from optix_e2e.camera_design.detection import (
    _digest,
    detection_scores,
    evaluate_detection,
    map_resamples,
    paired_resamples,
    read_detections,
    saved_detections,
    write_detections,
)
from optix_e2e.camera_design.run import hooks_for
from optix_e2e.errors import InputError
from optix_e2e.parallel import Ranks
from optix_e2e.surrogate.ground_truth import exact_optics
from optix_e2e.tasks.detection import DetectionCamera, heldout_streets
from optix_e2e.torchfile import load_plain

RUN_FILES = ("config.json", "results.json", "nominal_state.pt", "end_to_end_state.pt")


def finished_run(run: Path) -> tuple[DesignConfig, dict]:
    """(config, results) of a finished detection run, or one line on what it is not."""
    missing = [f for f in RUN_FILES if not (run / f).is_file()]
    if missing:
        raise SystemExit(f"{run}: not a finished design run (no {', '.join(missing)})")
    try:
        cfg = run_config(run).check()
        res = json.loads((run / "results.json").read_text())
    except (TypeError, ValueError, InputError) as err:  # damaged or hand-edited files
        raise SystemExit(f"{run}: not a readable design run ({err})") from None
    if cfg.task != "detection":
        raise SystemExit(f"{run}: a {cfg.task} run; this bench crosses detection runs")
    if (res.get("device", "cpu"), res.get("precision", "fp32")) != ("cpu", "fp32"):
        raise SystemExit(
            f"{run}: ran on {res.get('device')} at {res.get('precision')}; this bench evaluates on the CPU at fp32"
        )
    return cfg, res


def camera_state(state_path: Path) -> dict:
    """The camera's state dict saved in a design checkpoint, or one line on what is wrong."""
    try:
        return load_plain(state_path, "design checkpoint")["camera"]
    except (InputError, KeyError, TypeError) as err:
        raise SystemExit(f"{state_path}: not a readable design checkpoint ({err})") from None


def load_processing(hooks, sur, frame, st: dict, optics: FixedOptics) -> DetectionCamera:
    """A detection camera with ``optics`` and the ISP and detector of the camera state ``st``."""
    cam = hooks.build_camera(sur, frame, fixed_optics=optics)
    for prefix, module in (("camera.isp.", cam.isp), ("detector.", cam.detector)):
        module.load_state_dict({k[len(prefix) :]: v for k, v in st.items() if k.startswith(prefix)})
    return cam.eval()


def gaussian_blur(psf: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Each PSF [..., S, S] convolved with a normalized Gaussian of ``sigma_px`` pixels
    (zero outside the window), then scaled back to its own sum: more blur, the same light."""
    r = max(1, int(math.ceil(4 * sigma_px)))
    x = torch.arange(-r, r + 1, dtype=psf.dtype)
    g = torch.exp(-0.5 * (x / sigma_px) ** 2)
    g = g / g.sum()
    flat = psf.reshape(-1, 1, *psf.shape[-2:])
    out = torch.nn.functional.conv2d(flat, g.view(1, 1, 1, -1), padding=(0, r))
    out = torch.nn.functional.conv2d(out, g.view(1, 1, -1, 1), padding=(r, 0)).reshape(psf.shape)
    return out * (psf.sum((-2, -1), keepdim=True) / out.sum((-2, -1), keepdim=True).clamp_min(1e-30))


def effect(name: str, a: dict, b: dict) -> dict:
    """Cell b minus cell a, from their bootstrap resamples (the same scenes and seed)."""
    p = paired_resamples(a, b)
    return {"name": name, "map_50": p["map_50"], "map": p["map"], "dark_map_50": p["dark"]["map_50"]}


def cell(x: dict) -> str:
    lo, hi = x["ci95"]
    return f"{x['mean']:+.3f} [{lo:+.3f}, {hi:+.3f}]"


def seeds_table(swaps: list[Path], out_dir: Path) -> dict:
    """Each effect of several seeds' swaps: per seed, mean and t interval over the seeds."""
    from alg1_vs_vanilla import seeds_interval

    res = []
    for d in swaps:
        f = d / "detection_swap.json"
        if not f.is_file():
            raise SystemExit(f"{d}: no detection_swap.json (run this bench on the seed's runs first)")
        try:
            res.append(json.loads(f.read_text()))
        except ValueError as err:
            raise SystemExit(f"{f}: not a readable swap ({err})") from None
    names = [e["name"] for e in res[0]["effects"]]
    if any([e["name"] for e in r["effects"]] != names for r in res):
        raise SystemExit("the swaps hold different effects (one of them without a second run?)")
    rows = []
    for i, name in enumerate(names):
        row = {"name": name}
        for k in ("map_50", "map", "dark_map_50"):
            d = [r["effects"][i][k]["mean"] for r in res]
            row[k] = {"per_seed": d, "mean": sum(d) / len(d), "seeds_ci95": seeds_interval(d)}
        rows.append(row)
    out = {"swaps": [str(d) for d in swaps], "f_numbers": [r["f_numbers"] for r in res], "effects": rows}
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "swap_seeds.json").write_text(json.dumps(out, indent=2))

    def fmt(x: dict) -> str:
        ci = x["seeds_ci95"]
        per = " / ".join(f"{v:+.3f}" for v in x["per_seed"])
        return f"{per}; **{x['mean']:+.3f}**" + (f" [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci else "")

    md = [
        f"# Lens x processing over {len(res)} seeds: each effect per seed; mean [t interval over seeds]",
        "",
        "Swaps: " + ", ".join(f"`{d}`" for d in swaps) + ".",
        "",
        "| effect | mAP@0.5 | mAP | dark mAP@0.5 |",
        "|---|---|---|---|",
    ]
    md += [f"| {r['name']} | {fmt(r['map_50'])} | {fmt(r['map'])} | {fmt(r['dark_map_50'])} |" for r in rows]
    (out_dir / "swap_seeds.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    if "--seeds" in (sys.argv[1:] if argv is None else argv):
        ap.add_argument("--seeds", type=Path, nargs="+", required=True)
        ap.add_argument("--out", type=Path, required=True)
        a = ap.parse_args(argv)
        return seeds_table(a.seeds, a.out)
    ap.add_argument("run", type=Path)
    ap.add_argument("run_b", type=Path, nargs="?")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: the run's)")
    ap.add_argument(
        "--blur-um",
        type=float,
        default=None,
        help="also a control lens: the nominal's PSFs blurred by a Gaussian of this sigma (um, on the sensor)",
    )
    ap.add_argument(
        "--recheck", action="store_true", help="evaluate the diagonal again and compare it with the saved detections"
    )
    a = ap.parse_args(argv)
    if a.blur_um is not None and not a.blur_um > 0:
        ap.error(f"--blur-um must be > 0 um, got {a.blur_um}")
    runs = {"A": a.run} | ({"B": a.run_b} if a.run_b else {})
    loaded = {k: finished_run(r) for k, r in runs.items()}
    cfg, res = loaded["A"]
    if a.threads is not None:
        cfg = DesignConfig(**{**cfg.to_json(), "threads": a.threads}).check()
    if "B" in loaded:
        cb, rb = loaded["B"]
        keys = ("eval_scenes", "crop_hw", "seed", "space", "surrogate", "detector", "patch", "precision")
        same = all(getattr(cb, k) == getattr(cfg, k) for k in keys)
        if not same or rb["design"]["nominal"] != res["design"]["nominal"]:
            raise SystemExit(
                f"{a.run_b}: another held-out set, nominal lens or detector than {a.run} ({', '.join(keys)})"
            )
    _, task, frame, sur = start_run(cfg, a.out)
    hooks = hooks_for(cfg, "cpu")
    hooks.check(sur, Ranks())

    # the lenses: nominal, then each run's end-to-end lens, exact PSFs at each one's focus
    lens_values = {"nominal": res["design"]["nominal"]} | {
        f"e2e {k}": loaded[k][1]["design"]["end_to_end"] for k in runs
    }
    names = list(lens_values)
    values = torch.tensor([lens_values[n] for n in names], dtype=torch.float64)
    t0 = time.perf_counter()
    exact = exact_optics(sur, values.numpy(), fallback=hooks.exact_fallback)
    print(f"exact PSFs of {len(names)} lenses: {time.perf_counter() - t0:.0f} s", flush=True)
    # each lens's (PSFs, vignetting, field heights) as the design run passes them (its cache keys)
    raw = {
        n: (
            exact["psf"][i],
            exact["vignetting"][i],
            design_field_heights(sur, values[i].numpy(), exact["image_distance"][i]),
        )
        for i, n in enumerate(names)
    }
    f_numbers = {n: hooks.f_number(values[i]) for i, n in enumerate(names)}
    optics = {
        n: FixedOptics(*raw[n], patch=cfg.patch, full_field_px=frame.full_field_px, f_number=f_numbers[n])
        for n in names
    }
    if a.blur_um is not None:  # the control: the nominal lens, only blurred (no more light)
        name = f"nominal blur {a.blur_um:g} um"
        psf, vig, fh = raw["nominal"]
        raw[name] = (gaussian_blur(torch.as_tensor(psf), a.blur_um / sur.pitch_um), vig, fh)
        f_numbers[name] = f_numbers["nominal"]
        optics[name] = FixedOptics(
            *raw[name], patch=cfg.patch, full_field_px=frame.full_field_px, f_number=f_numbers[name]
        )
        names.append(name)
    samples = heldout_streets(
        cfg.eval_scenes, cfg.crop_hw, exact["psf"].shape[-1] // 2, (task.level_min, task.level_max), frame
    )
    # the processing: the nominal baseline's (of RUN) and each run's end-to-end camera's
    procs = {"nominal": (a.run, "nominal")} | {f"e2e {k}": (r, "end_to_end") for k, r in runs.items()}
    preds: dict[tuple[str, str], list] = {}
    recheck: dict[str, dict] = {}
    samples_key = eval_cache.samples_digest(samples)
    (a.out / "cells").mkdir(parents=True, exist_ok=True)
    for pname, (run, who) in procs.items():
        state = camera_state(run / f"{who}_state.pt")  # once per processing, for every lens
        for lname in names:
            cam = load_processing(hooks, sur, frame, state, optics[lname])
            # what the detections depend on, as the design run keys its own (code, sensor, lens,
            # processing, scenes): the run's saved detections count only under the same key
            key = _digest(*raw[lname], f_numbers[lname], cam, len(samples), samples_key)
            own = run / f"detections_{who}_exact.json" if lname == pname else None
            path = a.out / "cells" / f"{lname}__{pname}.json".replace(" ", "_")
            hit = None if a.recheck else read_detections(own or path, key)
            if hit is not None:
                preds[(lname, pname)] = hit[0]
            else:
                t0 = time.perf_counter()
                preds[(lname, pname)] = evaluate_detection(cam, samples)
                write_detections(path, key, time.perf_counter() - t0, samples, preds[(lname, pname)])
                print(f"lens {lname} behind processing {pname}: {time.perf_counter() - t0:.0f} s", flush=True)
            saved = saved_detections(own, samples) if own and a.recheck else None
            if saved is not None:  # the run's saved and this fresh evaluation of the same camera
                was, now = (detection_scores(p, samples, task.dark) for p in (saved, preds[(lname, pname)]))
                recheck[lname] = {k: {"saved": was[k], "again": now[k]} for k in ("map_50", "map")}
    scores = {k: detection_scores(p, samples, task.dark) for k, p in preds.items()}
    t0 = time.perf_counter()  # every cell's bootstrap resamples once (the same resamples for all)
    boots = {k: map_resamples(p, samples, cfg.bootstrap, cfg.seed, task.dark) for k, p in preds.items()}
    print(f"bootstrap ({cfg.bootstrap} resamples) of {len(boots)} cells: {time.perf_counter() - t0:.0f} s", flush=True)
    effects = []
    for pname in procs:  # the lens's effect, processing held
        for lname in names[1:]:
            name = f"lens {lname} - nominal, processing {pname}"
            effects.append(effect(name, boots[("nominal", pname)], boots[(lname, pname)]))
        if "e2e B" in names:
            name = f"lens e2e A - e2e B, processing {pname}"
            effects.append(effect(name, boots[("e2e B", pname)], boots[("e2e A", pname)]))
    for lname in names:  # the processing's effect, lens held
        for pname in list(procs)[1:]:
            name = f"processing {pname} - nominal, lens {lname}"
            effects.append(effect(name, boots[(lname, "nominal")], boots[(lname, pname)]))
    # the whole cameras, each its own lens and processing (the runs' results.json / detection_compare.py)
    for k in runs:
        effects.append(effect(f"camera e2e {k} - nominal", boots[("nominal", "nominal")], boots[(f"e2e {k}",) * 2]))
    if "B" in runs:
        effects.append(effect("camera e2e A - e2e B", boots[("e2e B", "e2e B")], boots[("e2e A", "e2e A")]))
    out = {
        "runs": {k: str(r) for k, r in runs.items()},
        "n_scenes": len(samples),
        "f_numbers": {n: float(optics[n].f_number()) for n in names},
        "cells": [
            {"lens": ln, "processing": pn, "map_50": s["map_50"], "map": s["map"], "dark_map_50": s["dark"]["map_50"]}
            for (ln, pn), s in scores.items()
        ],
        "effects": effects,
        "recheck": recheck,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "detection_swap.json").write_text(json.dumps(out, indent=2))
    md = [
        f"# Lens x processing, {len(samples)} held-out street scenes, exact optics",
        "",
        "Runs: "
        + ", ".join(f"{k} = `{r}`" for k, r in runs.items())
        + ". f-numbers: "
        + ", ".join(f"{n} f/{f:.2f}" for n, f in out["f_numbers"].items())
        + ".",
        "",
        "| lens \\ processing | " + " | ".join(procs) + " |",
        "|---|" + "---|" * len(procs),
    ]
    for ln in names:
        md.append(
            f"| {ln} | "
            + " | ".join(
                f"{scores[(ln, pn)]['map_50']:.3f} / {scores[(ln, pn)]['map']:.3f} / {scores[(ln, pn)]['dark']['map_50']:.3f}"
                for pn in procs
            )
            + " |"
        )
    md += [
        "",
        "Cells: mAP@0.5 / mAP / dark mAP@0.5.",
        "",
        "| effect | mAP@0.5 | mAP | dark mAP@0.5 |",
        "|---|---|---|---|",
    ]
    md += [f"| {e['name']} | {cell(e['map_50'])} | {cell(e['map'])} | {cell(e['dark_map_50'])} |" for e in effects]
    (a.out / "detection_swap.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return out


if __name__ == "__main__":
    sys.exit(main() and 0)
