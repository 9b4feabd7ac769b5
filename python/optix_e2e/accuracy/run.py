"""``optix bench accuracy``: run the sweep, write the CSVs, the JSON summary and the charts."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path
from typing import Callable

from ..io import write_csv_atomic, write_record_atomic
from ..lens import Lens
from .chart import plot_methods, plot_sampling, summarize
from .sweep import Config, field_rows, method_rows, method_settings, spectral_rows

DEFAULT_LENSES = ("cooke-f50", "paper-triplet", "double-gauss-f5")
FIELD_FRACTIONS = {"axis": 0.0, "mid": 0.7, "edge": 1.0}


def write_csv(path: Path, rows: list[dict]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    write_csv_atomic(path, ([r.get(k, "") for k in keys] for r in rows), header=keys)


def run(
    out: "str | Path",
    lenses=DEFAULT_LENSES,
    quick: bool = False,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict:
    """The whole bench into ``out``: rows.csv (every measurement), summary.csv (per method
    and setting over the cases, with the Pareto front), sampling.csv (wavelengths per channel
    and field samples), accuracy.json, speed_accuracy.png, sampling.png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = Config()
    if quick:
        cfg.ref_start, cfg.ref_tol, cfg.repeats = 64, 2e-2, 1
    settings = method_settings(quick)
    loaded = [Lens.load(name) for name in lenses]
    fracs = {"axis": 0.0, "edge": 1.0} if quick else FIELD_FRACTIONS
    cases = [
        (lens, frac * lens.max_field_deg, wl)
        for lens in loaded
        for frac in fracs.values()
        for wl in ([lens.primary_wavelength_nm] if quick else lens.wavelengths_nm)
    ]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cases) + 2 * len(loaded), unit="case", desc="accuracy", dynamic_ncols=True)
    t0 = time.perf_counter()
    rows, sampling = [], []
    for lens, f, wl in cases:
        rows += method_rows(lens, f, wl, settings, cfg)
        if bar:
            bar.update()
    for lens in loaded:
        sampling += spectral_rows(lens, lens.max_field_deg, cfg)
        if bar:
            bar.update()
        sampling += field_rows(lens, lens.primary_wavelength_nm, cfg)
        if bar:
            bar.update()
    if bar:
        bar.close()
    summary = summarize(rows)
    write_csv(out / "rows.csv", rows)
    write_csv(out / "summary.csv", summary)
    write_csv(out / "sampling.csv", sampling)
    title = (
        f"{', '.join(lenses)}: {len(cases)} cases (fields {', '.join(fracs)}; "
        f"{'primary wavelength' if quick else 'each lens wavelength'}), {cfg.size}x{cfg.size} at {cfg.pixel_um} um, "
        f"vs Huygens converged by doubling"
    )
    plot_methods(summary, out / "speed_accuracy.png", title)
    plot_sampling(
        [r for r in sampling if r["experiment"] == "spectral"],
        [r for r in sampling if r["experiment"] == "fields"],
        out / "sampling.png",
    )
    report = {
        "lenses": list(lenses),
        "n_cases": len(cases),
        "quick": quick,
        "seconds": time.perf_counter() - t0,
        "size": cfg.size,
        "pixel_um": cfg.pixel_um,
        "reference": {
            "method": "huygens",
            "start": cfg.ref_start,
            "tol": cfg.ref_tol,
            "samples": sorted({r["reference_samples"] for r in rows}),
        },
        "pareto_front": [
            {k: s[k] for k in ("method", "setting", "time_s", "rel_l1", "image_rel_l2")}
            for s in sorted(summary, key=lambda s: s["time_s"])
            if s["pareto"]
        ],
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine()},
        "files": ["rows.csv", "summary.csv", "sampling.csv", "speed_accuracy.png", "sampling.png"],
    }
    write_record_atomic(out / "accuracy.json", report)
    return report
