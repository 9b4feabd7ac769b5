"""How far off are the PSFs `auto` flags? (docs/accuracy.md, "The flagged PSFs of a dataset run")

    python benches/auto_flagged.py DATASET [--cases 12] [--crop 64] --out DIR

A dataset run's shards record, per design, the PSFs for which `auto` predicted no method within
its target ("auto: no method is predicted to meet the accuracy target ...; used the most
accurate, M N=K (predicted P%)"). This bench takes --cases of them, spread evenly over the
run's list, rebuilds each design as the dataset traced it (manifest apertures, recorded image
distance) and measures, against the converged Huygens reference:

* auto's PSF now (the method it chooses with today's engine), and the method the run recorded;
* the fast FFT at its own grid and with >= 2048 cells across the pupil, where it applies (its
  convergence in the grid);
* the geometric PSF at N = 256.

The Huygens reference over the whole window costs minutes a PSF where the window is wide
(246 um at 1 um: its sum must be exact, docs/accuracy.md), so it is computed on the central
--crop x --crop pixels (pupil samples doubled from 256 until two agree within --tol) and every
PSF is compared on that crop (relative L1 over the crop). The full window is compared between
the fast FFT's two grids. Writes DIR/auto_flagged.csv and DIR/auto_flagged.json (the summary).
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

from optix_e2e import engine
from optix_e2e.accuracy.reference import converged_reference
from optix_e2e.dataset.manifest import refocused_designs

FLAG = re.compile(
    r"field ([0-9.e+-]+) deg, ([0-9.]+) nm: auto: no method is predicted to meet the accuracy target "
    r".*used the most accurate, (\S+ N=\d+) \(predicted ([0-9.]+)%\)"
)
OUTSIDE = re.compile(r"field ([0-9.e+-]+) deg, ([0-9.]+) nm: ([0-9.]+)% of the transmitted energy falls outside")


def flagged_cases(root: Path) -> list[dict]:
    """Every flagged PSF of the run: shard, design (global index), its row in the shard, field,
    wavelength, the method used, the predicted error and the share of light outside the window."""
    out = []
    for meta in sorted(root.glob("shards/*/shard.json")):
        m = json.loads(meta.read_text())
        rows = {int(d): i for i, d in enumerate(np.load(meta.parent / "design.npy"))}
        for design, warnings in sorted(m["warnings"].items(), key=lambda kv: int(kv[0])):
            outside = {(g[0], g[1]): float(g[2]) for g in (OUTSIDE.match(w) for w in warnings) if g}
            for w in warnings:
                g = FLAG.match(w)
                if g and int(design) in rows:
                    out.append(
                        dict(
                            shard=meta.parent.name,
                            design=int(design),
                            row=rows[int(design)],
                            field_deg=float(g[1]),
                            wavelength_nm=float(g[2]),
                            recorded=g[3],
                            predicted_pct=float(g[4]),
                            outside_pct=outside.get((g[1], g[2]), 0.0),
                        )
                    )
    return out


def crop(a: np.ndarray, c: int) -> np.ndarray:
    o = (a.shape[0] - c) // 2
    return a[o : o + c, o : o + c]


def rel(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.abs(a - ref).sum() / ref.sum())


def spread(cases: list, k: int) -> list:
    if k >= len(cases):
        return cases
    return [cases[i] for i in np.linspace(0, len(cases) - 1, k).round().astype(int)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path)
    ap.add_argument("--cases", type=int, default=12)
    ap.add_argument("--crop", type=int, default=64, help="the reference's central window (pixels)")
    ap.add_argument("--tol", type=float, default=5e-3, help="reference: successive Huygens agree within")
    ap.add_argument("--max-samples", type=int, default=2048)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    if not (a.dataset / "manifest.json").is_file():
        print(f"auto_flagged: {a.dataset} is not a dataset run (no manifest.json)", file=sys.stderr)
        return 2
    man = json.loads((a.dataset / "manifest.json").read_text())
    s = man["settings"]
    size, pixel = int(round(s["window_um"] / s["pixel_um"])), float(s["pixel_um"])
    if a.crop > size or (size - a.crop) % 2:
        print(
            f"auto_flagged: --crop {a.crop} must be at most {size} and differ from it by an even number",
            file=sys.stderr,
        )
        return 2
    every = flagged_cases(a.dataset)
    cases = spread(every, a.cases)
    print(f"{len(every)} flagged PSFs in {a.dataset}; measuring {len(cases)}", file=sys.stderr)
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for c in cases:
        shard = a.dataset / "shards" / c["shard"]
        p = np.load(shard / "params.npy")[c["row"] : c["row"] + 1]
        z = np.load(shard / "image_distance.npy")[c["row"] : c["row"] + 1]
        js = json.dumps(refocused_designs(man, p, z)[0])
        kw = dict(field_deg=c["field_deg"], wavelength_nm=c["wavelength_nm"], pixel_um=pixel)
        t = time.perf_counter()
        try:
            ref = converged_reference(js, size=a.crop, start=256, tol=a.tol, max_samples=a.max_samples, **kw)
        except Exception as exc:  # noqa: BLE001 - a reference that does not converge is a row too
            print(f"design {c['design']} {c['field_deg']:.2f} deg: no reference ({exc})", file=sys.stderr)
            rows.append(dict(c, reference="none"))
            continue
        row = dict(
            c, ref_pupil_samples=ref.pupil_samples, ref_convergence=ref.convergence, ref_s=time.perf_counter() - t
        )
        row["crop_share_of_window"] = None
        t = time.perf_counter()
        psf, diag = engine.psf(js, method="auto", size=size, **kw)
        row.update(
            auto_now=diag.get("auto", {}).get("choice"),
            auto_now_pupil=diag.get("pupil_eval"),
            auto_now_s=time.perf_counter() - t,
        )
        row["auto_now_pct"] = 100 * rel(crop(psf, a.crop), ref.psf)
        row["auto_now_predicted_pct"] = 100 * (diag.get("auto", {}).get("predicted_rel_l1") or float("nan"))
        row["crop_share_of_window"] = float(crop(psf, a.crop).sum() / max(psf.sum(), 1e-300))
        row["window_share_of_light"] = float(psf.sum() / max(diag.get("transmitted_fraction", 1.0), 1e-300))
        method, n = c["recorded"].split(" N=")
        t = time.perf_counter()
        rec, _ = engine.psf(
            js, method=method.split("-")[0], fast=method.endswith("-fast"), pupil_samples=int(n), size=size, **kw
        )
        row.update(recorded_pct=100 * rel(crop(rec, a.crop), ref.psf), recorded_s=time.perf_counter() - t)
        t = time.perf_counter()
        geo, _ = engine.psf(js, method="geometric", pupil_samples=256, size=size, **kw)
        row.update(geometric256_pct=100 * rel(crop(geo, a.crop), ref.psf), geometric256_s=time.perf_counter() - t)
        try:
            t = time.perf_counter()
            fast, fd = engine.psf(js, method="fft", fast=True, pupil_samples=64, size=size, **kw)
            row["fast_s"] = time.perf_counter() - t
            row["fast_fallback"] = fd.get("fast_fallback")
            row["fast_pupil"] = fd.get("pupil_eval")
            g = int(fd.get("fft_grid") or 0)
            row.update(fast_grid=g, fast_pct=100 * rel(crop(fast, a.crop), ref.psf))
            if not fd.get("fast_fallback") and g:
                # the same fast path with at least 2048 cells across the pupil (pupil_samples sets
                # the fewest; the grid follows): its convergence in the grid
                fine, fd4 = engine.psf(js, method="fft", fast=True, pupil_samples=2048, size=size, **kw)
                row.update(
                    fast_fine_grid=int(fd4.get("fft_grid") or 0),
                    fast_vs_fine_window_pct=100 * rel(fast, fine),
                    fast_fine_pct=100 * rel(crop(fine, a.crop), ref.psf),
                )
        except engine.PsfError as exc:
            row["fast_fallback"] = f"refused: {exc}"
        rows.append(row)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
    keys = sorted({k for r in rows for k in r}, key=lambda k: [*rows[0], k].index(k) if k in rows[0] else 99)
    with open(a.out / "auto_flagged.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    done = [r for r in rows if "auto_now_pct" in r]
    summary = {
        "dataset": str(a.dataset),
        "flagged_in_run": len(every),
        "measured": len(done),
        "crop_px": a.crop,
        "recorded_within_2pct": sum(r["recorded_pct"] <= 2 for r in done),
        "auto_now_within_2pct": sum(r["auto_now_pct"] <= 2 for r in done),
        "recorded_pct_median": float(np.median([r["recorded_pct"] for r in done])) if done else None,
        "auto_now_pct_median": float(np.median([r["auto_now_pct"] for r in done])) if done else None,
        "by_recorded_method": {},
    }
    for m in sorted({r["recorded"].split(" N=")[0] for r in done}):
        sel = [r for r in done if r["recorded"].startswith(m + " ")]
        summary["by_recorded_method"][m] = {
            "n": len(sel),
            "recorded_pct": [round(r["recorded_pct"], 3) for r in sel],
            "auto_now_pct": [round(r["auto_now_pct"], 3) for r in sel],
            "predicted_pct": [r["predicted_pct"] for r in sel],
        }
    (a.out / "auto_flagged.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
