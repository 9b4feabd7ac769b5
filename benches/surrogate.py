#!/usr/bin/env python3
"""Surrogate and renderer speed: RGB PSFs per second from the optics surrogate against the
exact engine at the same output, and the time to render a 1920x1200 RGB frame with the 13
field PSFs.

    python benches/surrogate.py [--model paper-triplet] [-n 256] [--device cpu|cuda] [--json]

One "PSF" here is one field's RGB PSF (3 channels, the surrogate's 21 x 21 sensor-pitch
window for the shipped model) with its vignetting. The engine figure is ``psf_batch`` as
the dataset calls it (FFT/auto PSFs on the 1 um grid, integrated to the sensor pitch) on
``n`` refocused designs of the model's space, 13 fields each; refocusing is not timed. The
surrogate figures are inference in batches of ``--batch`` designs (x 13 fields), and
forward + backward for one design's 13 fields (what a lens-optimization step pays). The
render figures are ``optix_e2e.optics.render.render`` forward and forward + backward, with the
surrogate's PSFs, at 64 and 128 px patches. Medians of ``--repeat`` runs. It measures; it
asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dataset import engine_only  # noqa: E402  (the dataset bench's engine timing)

from optix_e2e.dataset import DatasetSettings, generate  # noqa: E402
from optix_e2e.optics.differentiable import DifferentiableOptics  # noqa: E402
from optix_e2e.optics.render import render  # noqa: E402
from optix_e2e.surrogate import OpticsSurrogate  # noqa: E402


def _median_s(fn, repeat: int) -> float:
    fn()  # warm-up
    ts = []
    for _ in range(repeat):
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        t = time.perf_counter()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="paper-triplet")
    ap.add_argument("-n", type=int, default=256, help="designs for the engine timing")
    ap.add_argument("--batch", type=int, default=64, help="designs per surrogate call")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true", help="print only the JSON object")
    a = ap.parse_args()
    dev = torch.device(a.device)
    model = OpticsSurrogate.load(a.model).to(dev)
    k = len(model.fields_deg)
    man = model.manifest
    s = DatasetSettings.of_manifest(man["settings"])
    with tempfile.TemporaryDirectory() as tmp:
        space_spec = man["space"]["lens"] or "paper-triplet"
        generate(space_spec, a.n, 123, tmp, s, progress=False)
        engine_designs_per_s = engine_only(tmp)
    lo, hi = model.param_min.float(), model.param_max.float()
    params = lo + (hi - lo) * torch.rand(a.batch, len(lo), generator=torch.Generator().manual_seed(0))
    params = params.to(dev)

    with torch.no_grad():
        infer_s = _median_s(lambda: model.psfs(params), a.repeat)
    optics = DifferentiableOptics(model).to(dev)

    def grad_step():
        psf, vig = optics.psfs()
        (psf.square().sum() + vig.sum()).backward()

    grad_s = _median_s(grad_step, a.repeat)
    frame = torch.rand(1, 3, 1200, 1920, generator=torch.Generator().manual_seed(1)).to(dev)
    with torch.no_grad():
        psf, vig = optics.psfs()
    rend = {}
    for patch in (64, 128):
        with torch.no_grad():
            rend[f"render_s_patch{patch}"] = _median_s(
                lambda: render(frame, psf, model.fields, vig, patch=patch), max(1, a.repeat // 2)
            )

        def through_lens(patch=patch):  # lens parameters -> surrogate -> render -> loss, and back
            p, v = optics.psfs()
            render(frame, p, model.fields, v, patch=patch).mean().backward()

        rend[f"render_fwd_bwd_s_patch{patch}"] = _median_s(through_lens, max(1, a.repeat // 2))
    sur_rate = a.batch * k / infer_s
    eng_rate = engine_designs_per_s * k
    out = {
        "model": a.model,
        "psf_shape": [model.cfg.channels, model.cfg.psf_size, model.cfg.psf_size],
        "fields": k,
        "device": str(dev),
        "torch_threads": torch.get_num_threads(),
        "surrogate_rgb_psfs_per_s": sur_rate,
        "surrogate_batch_designs": a.batch,
        "engine_rgb_psfs_per_s": eng_rate,
        "engine_designs": a.n,
        "speedup": sur_rate / eng_rate,
        "surrogate_design_fwd_bwd_s": grad_s,
        "render_frame": [1200, 1920],
        **rend,
        "machine": {
            "cpus": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
            "gpu": torch.cuda.get_device_name(0) if dev.type == "cuda" else None,
        },
    }
    print(json.dumps(out, indent=None if a.json else 2))


if __name__ == "__main__":
    main()
