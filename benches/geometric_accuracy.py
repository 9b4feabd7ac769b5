"""Accuracy and cost of the interpolated geometric PSF (crates/psf-engine/src/psf/geometric.rs)
on the designs an FFT dataset run refused, against the converged Huygens reference
(docs/accuracy.md, "Large spots").

    optix dataset generate paper-triplet-detect-wide -n 16 --seed 0 --window-um 246 \\
        --pixel-um 1 --psf-method fft --pupil-samples 256 --out DIR
    python benches/geometric_accuracy.py DIR --cases 6 --out rows.csv

For each refused design (its refused field and wavelength, parsed from the shard's
``failures``) the design is rebuilt as the dataset built it (the space applied to the base
with the dataset's apertures, best focus), then: geometric PSFs at N = 64 ... 512 rays across
the pupil, the ``auto`` PSF, and the Huygens reference (pupil samples doubled from 256 until
two agree within --tol).  Errors: relative L1 over the window (sum |a - ref| / sum ref), and the
same absolute error over the transmitted energy (sum |a - ref| / transmitted fraction), which
is the one that stays meaningful when most of the light falls outside the window.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

from optix_e2e import engine
from optix_e2e.accuracy.reference import Reference, converged_reference
from optix_e2e.dataset.settings import DatasetSettings
from optix_e2e.lens.apertures import engine_base
from optix_e2e.lens_design.focus import refocus_many
from optix_e2e.lens_design.space import load_space

FIELD_WL = re.compile(r"at ([0-9.e+-]+) deg, ([0-9.]+) nm")


def refused_cases(root: Path) -> list[tuple[int, dict, float, float]]:
    """(design, lens dict, field, wavelength) of each design the run refused in the PSF."""
    man = json.loads((root / "manifest.json").read_text())
    s = DatasetSettings.of_manifest(man["settings"])
    space, base = load_space(man["space"]["source"])
    fields = man["fields_deg"]
    wavelengths = sorted({wl for c in man["channels"] for wl, _ in c})
    nf = min(len(fields), s.focus_fields)
    focus_fields = [fields[i] for i in np.unique(np.linspace(0, len(fields) - 1, nf).round().astype(int))]
    traced = engine_base(base, s.apertures)
    out = []
    for meta in sorted(root.glob("shards/*/shard.json")):
        for f in json.loads(meta.read_text())["failures"]:
            m = FIELD_WL.search(f["reason"])
            if "psf:" not in f["reason"] or not m:
                continue
            d = space.apply(traced, [f["params"][k] for k in space.names])
            err = refocus_many(
                [d],
                s.focus,
                focus_fields,
                wavelengths,
                primary_nm=base.primary_wavelength_nm,
                rings=s.focus_rings,
                aiming=s.aiming,
            )[0]
            if err is None:
                out.append((f["design"], d, float(m.group(1)), float(m.group(2))))
    return out


def blocks_rel_l1(a: np.ndarray, ref: np.ndarray, k: int) -> float:
    """Relative L1 of the k x k block sums (about the sensor's 5.86 um pitch at k = 6, 1 um)."""
    m = (a.shape[0] // k) * k
    sa = a[:m, :m].reshape(m // k, k, m // k, k).sum(axis=(1, 3))
    sr = ref[:m, :m].reshape(m // k, k, m // k, k).sum(axis=(1, 3))
    return float(np.abs(sa - sr).sum() / sr.sum())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", type=Path, nargs="?", help="an FFT dataset run's directory (its refused designs)")
    ap.add_argument("--lens", help="instead: this bundled lens, defocused by each --defocus (mm), on axis")
    ap.add_argument("--defocus", type=float, nargs="+", default=[0.3, 1.0, 3.0])
    ap.add_argument("--wavelength", type=float, default=550.0)
    ap.add_argument("--pixel-um", type=float, default=1.0)
    ap.add_argument("--cases", type=int, default=6)
    ap.add_argument("--samples", type=int, nargs="+", default=[64, 128, 256, 512])
    ap.add_argument("--tol", type=float, default=0.01, help="reference: successive Huygens agree within")
    ap.add_argument("--max-samples", type=int, default=2048)
    ap.add_argument("--size", type=int, help="window pixels (default: the dataset's); the Huygens cost grows with it")
    ap.add_argument("--start", type=int, default=256, help="reference: first pupil sampling")
    ap.add_argument("--skip", type=int, default=0, help="skip the first refused cases")
    ap.add_argument("--cache", type=Path, help="keep the reference PSFs here (.npz) and reuse them")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    if a.lens:
        from optix_e2e.lens import Lens

        data = json.loads(Lens.load(a.lens).to_engine_json())
        cases = []
        for dz in a.defocus:
            d = json.loads(json.dumps(data))
            d["surfaces"][-1]["thickness"] = float(d["surfaces"][-1]["thickness"]) + dz
            cases.append((f"{a.lens} +{dz} mm", d, 0.0, a.wavelength))
        size, pixel = a.size or 246, a.pixel_um
    else:
        man = json.loads((a.dataset / "manifest.json").read_text())
        size, pixel = (
            int(round(man["settings"]["window_um"] / man["settings"]["pixel_um"])),
            man["settings"]["pixel_um"],
        )
        size = a.size or size
        cases = refused_cases(a.dataset)[a.skip : a.skip + a.cases]
    rows = []
    for design, d, field, wl in cases:
        js = json.dumps(d)
        kw = dict(field_deg=field, wavelength_nm=wl, pixel_um=pixel, size=size)
        t = time.perf_counter()
        key = hashlib.sha256(f"{js}|{field}|{wl}|{size}|{pixel}|{a.tol}".encode()).hexdigest()[:16]
        cached = a.cache / f"ref_{key}.npz" if a.cache else None
        if cached is not None and cached.is_file():
            z = np.load(cached)
            ref = Reference(
                z["psf"], None, int(z["n"]), float(z["conv"]), float(z["s"]), {"transmitted_fraction": float(z["tr"])}
            )
        else:
            try:
                ref = converged_reference(
                    js, field, wl, size=size, pixel_um=pixel, start=a.start, tol=a.tol, max_samples=a.max_samples
                )
            except Exception as exc:  # noqa: BLE001 - a reference that does not converge is a row too
                print(f"design {design} {field:.2f} deg {wl} nm: no reference ({exc})", file=sys.stderr)
                continue
            if cached is not None:
                a.cache.mkdir(parents=True, exist_ok=True)
                tr = ref.diagnostics.get("transmitted_fraction", 1.0)
                np.savez(cached, psf=ref.psf, n=ref.pupil_samples, conv=ref.convergence, s=ref.seconds, tr=tr)
        t_ref = ref.seconds if cached is not None and cached.is_file() else time.perf_counter() - t
        tr = ref.diagnostics.get("transmitted_fraction", 1.0)
        base_row = {
            "design": design,
            "field_deg": round(field, 4),
            "wavelength_nm": wl,
            "ref_pupil_samples": ref.pupil_samples,
            "ref_convergence": ref.convergence,
            "ref_s": round(t_ref, 2),
            "energy_in_window": float(ref.psf.sum() / tr),
        }
        settings = [("geometric", n) for n in a.samples] + [("auto", 64)]
        for method, n in settings:
            t = time.perf_counter()
            psf, diag = engine.psf(js, method=method, pupil_samples=n, **kw)
            secs = time.perf_counter() - t
            err = np.abs(psf - ref.psf).sum()
            row = dict(base_row)
            row.update(
                method=method if method != "auto" else f"auto ({diag.get('auto', {}).get('choice')})",
                pupil_samples=n,
                seconds=round(secs, 4),
                rel_l1=float(err / ref.psf.sum()),
                rel_l1_transmitted=float(err / tr),
                rel_l1_6px=blocks_rel_l1(psf, ref.psf, 6),
                rms_spot_um=diag.get("rms_spot_um", diag.get("auto", {}).get("probe", {}).get("spot_rms_um")),
                airy_radius_um=diag.get("airy_radius_um"),
                subsamples_max=diag.get("geometric_subsamples_max"),
                predicted_rel_l1=diag.get("auto", {}).get("predicted_rel_l1"),
            )
            rows.append(row)
            print(json.dumps(row), flush=True)
    if a.out and rows:
        with open(a.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
