"""Paper Table 5 and the numbers behind Fig. 11's PSF comparison, from an `optix design` run.

    python benches/table5.py RUN_DIR [RUN_DIR ...] [--out DIR]

Reads RUN_DIR/results.json (held-out image quality of both cameras under the engine's exact
PSFs, with the paired bootstrap intervals) and the two lens reports (RUN_DIR/report/*/report.json:
per-field polychromatic RMS spot, Strehl ratio and MTF of each lens). Writes DIR/table5.csv,
DIR/table5.md and DIR/psf_compactness.csv (default DIR: RUN_DIR), and prints the markdown.
Nothing is recomputed: every figure is the run's own (the PSF grids themselves are the run's
psf_nominal.png and psf_end_to_end.png). With several runs (the same task and budget, other
seeds) the table is the first run's, and DIR/table5_seeds.csv and a second markdown table give
each run's paired differences and their mean over the runs with Student's t interval over the
seeds (how much a training run varies; docs/e2e.md).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

from optix_e2e.lens.mtf import NYQUIST_5P86_UM
from optix_e2e.lens_design.report import DEFAULT_MTF_FREQS

METRICS = [
    ("1 - LPIPS", "one_minus_lpips", "lpips", -1.0),
    ("PSNR (dB)", "psnr_db", "psnr_db", 1.0),
    ("SSIM", "ssim", "ssim", 1.0),
    ("HaarPSI", "haarpsi", "haarpsi", 1.0),
]
NYQUIST = round(NYQUIST_5P86_UM, 2)  # cycles/mm at the 5.86 um pixel pitch, a key of the reports' MTF
assert NYQUIST in DEFAULT_MTF_FREQS


def _fmt(v: float, metric: str) -> str:
    return f"{v:.2f}" if metric == "psnr_db" else f"{v:.3f}"


def table_rows(res: dict) -> list[dict]:
    """One row per camera and one for the paired difference (end-to-end minus nominal); 1 -
    LPIPS's difference is minus LPIPS's, its interval flipped."""
    rows = []
    isp = {"iq-hardware": " with hardware ISP", "iq-software": " with software ISP"}.get(res["task"], "")
    for who, label in (("end_to_end", f"End-to-end{isp}"), ("nominal", f"Nominal{isp}")):
        rows.append({"method": label, **{key: res[who][key] for _, key, _, _ in METRICS}})
    diff = {"method": "difference (paired 95 % CI)"}
    for _, key, src, sign in METRICS:
        p = res["paired"][src]
        lo, hi = sorted(sign * v for v in p["ci95"])
        diff[key] = (sign * p["mean"], lo, hi)
    rows.append(diff)
    return rows


def compactness_rows(run: Path) -> list[dict]:
    """Per field: each lens's polychromatic RMS spot, mean Strehl over the wavelengths and
    MTF at the sensor's Nyquist frequency (mean of tangential and sagittal)."""
    reps = {
        who: json.loads((run / "report" / who / "report.json").read_text(encoding="utf-8"))
        for who in ("nominal", "end_to_end")
    }
    if [f["field_deg"] for f in reps["nominal"]["fields"]] != [f["field_deg"] for f in reps["end_to_end"]["fields"]]:
        raise ValueError(f"{run}/report: the two lens reports have different fields")
    out = []
    for fn, fe in zip(reps["nominal"]["fields"], reps["end_to_end"]["fields"]):
        row = {"field_deg": fn["field_deg"]}
        for who, f in (("nominal", fn), ("end_to_end", fe)):
            mtf = f["mtf"][f"{NYQUIST:g}"]
            row[f"{who}_rms_spot_um"] = f["rms_spot_um"]
            row[f"{who}_strehl"] = sum(f["strehl_per_wavelength"]) / len(f["strehl_per_wavelength"])
            row[f"{who}_mtf_nyquist"] = 0.5 * (mtf["tangential"] + mtf["sagittal"])
        out.append(row)
    return out


def markdown(res: dict, rows: list[dict], comp: list[dict]) -> str:
    head = "| method | " + " | ".join(m for m, _, _, _ in METRICS) + " |"
    lines = [head, "|---" * (len(METRICS) + 1) + "|"]
    for r in rows:
        cells = []
        for _, key, _, _ in METRICS:
            v = r[key]
            cells.append(f"{v[0]:+.3f} [{v[1]:+.3f}, {v[2]:+.3f}]" if isinstance(v, tuple) else _fmt(v, key))
        lines.append(f"| {r['method']} | " + " | ".join(cells) + " |")
    n = res["held_out"]
    lines += [
        "",
        f"{n['n_images']} held-out images x {n['per_image']} positions ({n['n_samples']} samples), "
        f"exact engine PSFs, reference ISP; task {res['task']}, budget {res['budget']}, seed {res['seed']}.",
        "",
        "| field (deg) | RMS spot nominal / e2e (um) | Strehl nominal / e2e | MTF at Nyquist nominal / e2e |",
        "|---|---|---|---|",
    ]
    for c in comp:
        lines.append(
            f"| {c['field_deg']:.2f} | {c['nominal_rms_spot_um']:.2f} / {c['end_to_end_rms_spot_um']:.2f} | "
            f"{c['nominal_strehl']:.3f} / {c['end_to_end_strehl']:.3f} | "
            f"{c['nominal_mtf_nyquist']:.3f} / {c['end_to_end_mtf_nyquist']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def seeds_rows(results: list[dict]) -> list[dict]:
    """Each run's paired differences (end-to-end minus nominal; 1 - LPIPS as such), then their
    mean with Student's t 95 % interval over the runs."""
    from alg1_vs_vanilla import seeds_interval

    rows = [{"seed": r["seed"], **{key: table_rows(r)[-1][key][0] for _, key, _, _ in METRICS}} for r in results]
    mean = {"seed": "mean"}
    for _, key, _, _ in METRICS:
        d = [r[key] for r in rows]
        mean[key] = (sum(d) / len(d), *(seeds_interval(d) or (float("nan"), float("nan"))))
    return rows + [mean]


def write_table_csv(path: Path, first: str, rows: list[dict]) -> None:
    """One row per entry: its label, each metric, then each metric's interval (blank without one)."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(
            [first] + [k for _, k, _, _ in METRICS] + [f"{k}_ci95_{e}" for _, k, _, _ in METRICS for e in ("lo", "hi")]
        )
        for r in rows:
            vals = [r[k] for _, k, _, _ in METRICS]
            w.writerow(
                [r[first]]
                + [v[0] if isinstance(v, tuple) else v for v in vals]
                + [x for v in vals for x in ((v[1], v[2]) if isinstance(v, tuple) else ("", ""))]
            )


def _read_run(run: Path) -> dict:
    res = json.loads((run / "results.json").read_text(encoding="utf-8"))
    if "paired" not in res or "psnr_db" not in res.get("paired", {}):
        raise ValueError(f"{run}/results.json: not an image-quality design run (task {res.get('task')!r})")
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, nargs="+")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    out = a.out or a.run[0]
    try:
        results = [_read_run(r) for r in a.run]
        if len({(r["task"], r["budget"], tuple(r["design"]["parameters"])) for r in results}) > 1:
            raise ValueError("the runs differ in task, budget or lens space: not seeds of one experiment")
        res = results[0]
        rows = table_rows(res)
        comp = compactness_rows(a.run[0])
        seeds = seeds_rows(results) if len(results) > 1 else None
    except (OSError, ValueError, KeyError) as err:
        sys.exit(f"error: {err}")
    out.mkdir(parents=True, exist_ok=True)
    write_table_csv(out / "table5.csv", "method", rows)
    with open(out / "psf_compactness.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(comp[0]))
        w.writeheader()
        w.writerows(comp)
    md = markdown(res, rows, comp)
    if seeds:
        write_table_csv(out / "table5_seeds.csv", "seed", seeds)
        md += (
            "\nEnd-to-end minus nominal per seed, and the mean over the seeds with Student's t 95 % interval:\n\n"
            "| seed | " + " | ".join(m for m, _, _, _ in METRICS) + " |\n" + "|---" * (len(METRICS) + 1) + "|\n"
        )
        for r in seeds:
            cells = [
                f"{v[0]:+.3f} [{v[1]:+.3f}, {v[2]:+.3f}]" if isinstance(v, tuple) else f"{v:+.3f}"
                for v in (r[k] for _, k, _, _ in METRICS)
            ]
            md += f"| {r['seed']} | " + " | ".join(cells) + " |\n"
    (out / "table5.md").write_text(md, encoding="utf-8")
    print(md, end="")


if __name__ == "__main__":
    main()
