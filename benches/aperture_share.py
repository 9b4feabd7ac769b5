"""How much of Adam's full step a detection run's aperture took: from each run's
lens_path.csv (the lens after every lens step), config.json and results.json.

Adam moves the aperture's sigmoid argument u by at most about lr per step (times the run's
``design.step_scale`` for it under lens_steps = "range"); the share is the change of u over
the run divided by that reach, 1 where every step was a full step towards a faster lens. Also
the lens steps that opened the aperture and the f-number along the way.

    python benches/aperture_share.py benches/results/issue35/detect_quick benches/results/issue35/detect_full_seed{0,1,2}
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path


def aperture_share(run: Path) -> dict:
    missing = [f for f in ("config.json", "results.json", "lens_path.csv") if not (run / f).is_file()]
    if missing:
        raise SystemExit(f"{run}: not a finished design run (no {', '.join(missing)})")
    cfg = json.loads((run / "config.json").read_text())
    res = json.loads((run / "results.json").read_text())
    names = res["design"]["parameters"]
    if "f_number" not in names:
        raise SystemExit(f"{run}: its space has no f_number parameter")
    i = names.index("f_number")
    lo, hi = res["space"]["ranges"]["f_number"]
    with open(run / "lens_path.csv", newline="") as f:
        f_numbers = [float(r["f_number"]) for r in csv.DictReader(f)]
    scale = (res["design"].get("step_scale") or [1.0] * len(names))[i]
    lr = cfg["lr_vanilla"] if cfg["optimizer"] == "vanilla" else cfg["lr_optics"]

    def u(f: float) -> float:
        s = (f - lo) / (hi - lo)
        return math.log(s / (1 - s))

    steps = len(f_numbers) - 1
    return {
        "run": str(run),
        "optimizer": cfg["optimizer"],
        "lens_steps": cfg.get("lens_steps", "sigmoid"),
        "lr": lr,
        "step_scale": scale,
        "f_number_start": f_numbers[0],
        "f_number_end": f_numbers[-1],
        "lens_steps_taken": steps,
        "steps_opening": sum(b < a for a, b in zip(f_numbers, f_numbers[1:])),
        "share_of_full_step": (u(f_numbers[0]) - u(f_numbers[-1])) / (lr * scale * steps) if steps else 0.0,
        "f_number_every_50": f_numbers[::50] + ([f_numbers[-1]] if steps % 50 else []),
    }


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, help="write the rows as JSON here")
    args = ap.parse_args(argv)
    rows = [aperture_share(r) for r in args.runs]
    print("| run | lens steps | lr x scale | f-number | steps opening | share of Adam's full step |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {Path(r['run']).name} | {r['lens_steps']} | {r['lr']:g} x {r['step_scale']:.2f} | "
            f"{r['f_number_start']:.2f} -> {r['f_number_end']:.2f} | {r['steps_opening']} of {r['lens_steps_taken']} | "
            f"{r['share_of_full_step']:.2f} |"
        )
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1) + "\n")
    return rows


if __name__ == "__main__":
    main()
