#!/usr/bin/env python3
"""The detection design runs of several seeds in one table: per seed and over the seeds.

    python benches/detection_seeds.py RUN_DIR [RUN_DIR ...] --out OUT

Each RUN_DIR is a finished `optix design detection` run (its results.json). Per run: both
lenses' f-number and RMS spot per field, mAP@0.5, mAP@[.5:.95] and the dark objects' for both
cameras, and the paired end-to-end minus nominal differences with their 95 % bootstrap
interval over held-out scenes (as the run computed them). Over the runs: the mean of each
per-run difference with Student's t interval over seeds (how much a training run varies with
its seed: the interval the done-when asks for). Writes OUT.json and OUT.md. It measures; it
asserts nothing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: (results.json path of the paired difference, label)
DIFFS = (
    (("map_50",), "mAP@0.5"),
    (("map",), "mAP"),
    (("dark", "map_50"), "mAP@0.5, dark"),
    (("dark", "map"), "mAP, dark"),
)


def _get(d: dict, path: tuple[str, ...]):
    for k in path:
        d = d[k]
    return d


def run_row(run: Path) -> dict:
    try:
        res = json.loads((run / "results.json").read_text())
    except (OSError, ValueError) as e:
        raise SystemExit(f"{run}: not a finished design run (results.json: {e})") from None
    if res.get("task") != "detection":
        raise SystemExit(f"{run}: not a detection run ({res.get('task')!r})")
    cams = {
        who: {
            "f_number": res[who]["f_number"],
            "rms_spot_um": res[who]["rms_spot_um"],
            **{label: _get(res[who], path) for path, label in DIFFS},
        }
        for who in ("nominal", "end_to_end")
    }
    return {
        "run": str(run),
        "seed": res["seed"],
        "budget": res["budget"],
        "optimizer": res["optimizer"],
        "n_scenes": res["paired"]["n_images"],
        "report_fields_deg": res["nominal"]["report_fields_deg"],
        "cameras": cams,
        "lens_steps_cut": f"{res['training']['end_to_end']['cut_steps']} of {res['training']['end_to_end']['lens_steps']}",
        "paired": {label: _get(res["paired"], path) for path, label in DIFFS},
    }


def summary(rows: list[dict]) -> dict:
    from alg1_vs_vanilla import seeds_interval

    out = {}
    for _, label in DIFFS:
        d = [r["paired"][label]["mean"] for r in rows]
        out[label] = {"per_seed": d, "mean": float(np.mean(d)), "seeds_ci95": seeds_interval(d)}
    f = [r["cameras"]["end_to_end"]["f_number"] for r in rows]
    out["f_number_end_to_end"] = {"per_seed": f, "mean": float(np.mean(f))}
    return out


def table(rows: list[dict], summ: dict) -> str:
    def ci(p: dict) -> str:
        return f"{p['mean']:+.3f} [{p['ci95'][0]:+.3f}, {p['ci95'][1]:+.3f}]"

    fields = rows[0]["report_fields_deg"]
    lines = [
        "| seed | f-number, nominal -> end-to-end | mAP@0.5, nominal -> end-to-end | "
        + " | ".join(f"{label}, end-to-end minus nominal (95 % over scenes)" for _, label in DIFFS)
        + f" | RMS spot (um) at {' / '.join(f'{x:g}' for x in fields)} deg, end-to-end | lens steps cut |",
        "|---|---|---|" + "---|" * len(DIFFS) + "---|---|",
    ]
    for r in rows:
        n, e = r["cameras"]["nominal"], r["cameras"]["end_to_end"]
        lines.append(
            f"| {r['seed']} | {n['f_number']:.2f} -> {e['f_number']:.2f} | {n['mAP@0.5']:.3f} -> {e['mAP@0.5']:.3f} | "
            + " | ".join(ci(r["paired"][label]) for _, label in DIFFS)
            + f" | {' / '.join(f'{x:.1f}' for x in e['rms_spot_um'])} | {r['lens_steps_cut']} |"
        )
    if len(rows) > 1:
        cells = []
        for _, label in DIFFS:
            s = summ[label]
            lo, hi = s["seeds_ci95"]
            cells.append(f"**{s['mean']:+.3f}** [{lo:+.3f}, {hi:+.3f}]")
        lines.append(
            f"| mean of {len(rows)} (t interval over seeds) | f/{summ['f_number_end_to_end']['mean']:.2f} | | "
            + " | ".join(cells)
            + " | | |"
        )
    n0 = rows[0]["cameras"]["nominal"]["rms_spot_um"]
    return (
        "\n".join(lines)
        + f"\n\nThe nominal lens's RMS spot: {' / '.join(f'{x:.1f}' for x in n0)} um. "
        + f"{rows[0]['n_scenes']} held-out scenes per run, exact optics.\n"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True, help="OUT.json and OUT.md are written")
    args = ap.parse_args(argv)
    rows = [run_row(r) for r in args.runs]
    summ = summary(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Path(f"{args.out}.json").write_text(json.dumps({"runs": rows, "over_seeds": summ}, indent=1))
    md = table(rows, summ)
    Path(f"{args.out}.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
