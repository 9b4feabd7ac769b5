"""Two detection design runs' end-to-end cameras on the same held-out scenes: mAP of each and
the paired difference (B minus A) with its 95 % bootstrap interval over scenes, from the
detections the runs saved (Alg. 1 against vanilla at the same budget, issue 19).

    python benches/detection_compare.py runs/detect_quick runs/detect_quick_vanilla [--out cmp.json]

Both runs must have the same held-out set (eval_scenes, crop) and seed; the scenes are drawn
again from the runs' config.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from optix_e2e.camera_design.config import run_config
from optix_e2e.camera_design.detection import detection_scores, paired_map, saved_detections
from optix_e2e.tasks import SensorFrame, get_task
from optix_e2e.tasks.detection import heldout_streets


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_a", type=Path)
    ap.add_argument("run_b", type=Path)
    ap.add_argument("--camera", default="end_to_end", choices=["end_to_end", "nominal"])
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    for r in (args.run_a, args.run_b):
        if not ((r / "config.json").is_file() and (r / "results.json").is_file()):
            raise SystemExit(f"{r}: not a finished design run (no config.json or results.json)")
    cfgs = [run_config(r) for r in (args.run_a, args.run_b)]
    a, b = cfgs
    if (a.eval_scenes, a.crop_hw, a.seed) != (b.eval_scenes, b.crop_hw, b.seed):
        raise SystemExit("the two runs have different held-out sets (eval_scenes, crop or seed)")
    task = get_task(a.task)
    res = json.loads((args.run_a / "results.json").read_text())
    margin = int(res["exact_psf_energy_in_window"]["window_px"]) // 2
    samples = heldout_streets(a.eval_scenes, a.crop_hw, margin, (task.level_min, task.level_max), SensorFrame())
    preds = []
    for run in (args.run_a, args.run_b):
        saved = saved_detections(run / f"detections_{args.camera}_exact.json", samples)
        if saved is None:
            raise SystemExit(f"{run}: no readable detections of its {args.camera} camera for these scenes")
        preds.append(saved)
    out = {
        "a": str(args.run_a),
        "b": str(args.run_b),
        "camera": args.camera,
        "a_scores": detection_scores(preds[0], samples, task.dark),
        "b_scores": detection_scores(preds[1], samples, task.dark),
        "b_minus_a": paired_map(preds[0], preds[1], samples, a.bootstrap, a.seed, task.dark),
    }
    text = json.dumps(out, indent=1)
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
