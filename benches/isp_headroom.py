"""What the processing leaves to the lens: a software ISP on the design runs' held-out set.

For each software ISP given (default: the shipped one) and the classical pipeline alone
(isp/classical.py: calibrated black level, Malvar demosaick, 3x3, sRGB curve), the held-out
set of `optix design` (9 photos + 13 procedural scenes, 4 positions each over the frame, level
0.7, fixed noise seeds) is rendered through

* a perfect lens: the scene unblurred and unshaded (camera.PerfectOptics), and
* the nominal lens of the space: the engine's exact PSFs and relative illumination,

at normal light and at low light (exposure / 100, gain x 100), and scored by PSNR and SSIM
(8-bit output, as the design runs score), with LPIPS and the design runs' task loss L1 + LPIPS.
No fine-tuning: the network as shipped.

Two bounds split the error budget of the perfect lens (rows ``LIGHT/bound/...``):

* ``no-cfa``: a sensor that sees all three colours at every pixel (the same noise model, noise
  seeds, 3x3 and sRGB curve; no mosaic, so nothing to demosaick): what noise and the colour
  calibration alone cost. Above it, every dB a pipeline loses is demosaicking (and the
  denoising it does not do);
* ``classical-noise-free``: the classical pipeline on the noise-free RAW: what Malvar
  demosaicking alone costs.

    python benches/isp_headroom.py --out runs/isp_headroom [--isp runs/isp/software_isp.pt ...]
    python benches/isp_headroom.py --photos DIR [--photos DIR] --split test|val --out ...

With ``--photos`` the samples are photographs of prepared corpora at native scale instead
(tasks/samples.py photo_test_set, docs/test-split.md: the frame positions, level 0.7, the
split's own noise seeds): ``--split val`` a training corpus's validation photographs (for
decisions), ``--split test`` the untouched test split (to report only).

Writes headroom.json (means, per image kind) and prints one line per figure.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from optix_e2e import color
from optix_e2e.camera import Camera, FixedOptics, PerfectOptics, SensorStage, SoftwareISPStage, calibrated_preset
from optix_e2e.camera_design.build import SOFTWARE_ISP, base_lens_f_number, design_field_heights, load_surrogate
from optix_e2e.errors import InputError
from optix_e2e.isp.classical import ClassicalISP
from optix_e2e.isp.software import SoftwareISP
from optix_e2e.metrics.image import psnr, ssim
from optix_e2e.metrics.lpips import lpips
from optix_e2e.scenes.corpus import PhotoCorpus
from optix_e2e.sensor import get_preset
from optix_e2e.sensor.emva import expected_electrons, raw_from_electrons, simulate_raw
from optix_e2e.surrogate.ground_truth import exact_optics
from optix_e2e.tasks import SensorFrame, heldout_set
from optix_e2e.tasks.samples import POSITIONS, photo_test_set


class _Classical(torch.nn.Module):
    def __init__(self, preset):
        super().__init__()
        self.net = ClassicalISP(preset)

    def forward(self, raw):
        return self.net(raw)

    final = forward


def _no_cfa(scene: torch.Tensor, preset, to_linear: torch.Tensor, seed: int) -> torch.Tensor:
    """[3, H, W] linear scene -> sRGB through a sensor with all three colours at each pixel."""
    p = get_preset(preset)
    y = raw_from_electrons(expected_electrons(scene[None], p), p, generator=torch.Generator().manual_seed(seed))
    lin = torch.einsum("ij,bjhw->bihw", to_linear.to(y), y - p.black_level_dn)
    return color.linear_to_srgb(lin.clamp(0, 1))


def _score(rows: list, key: str, res: dict) -> None:
    photo = [r for r in rows if not r[0].startswith("procedural:")]
    proc = [r for r in rows if r[0].startswith("procedural:")]
    res[key] = {
        "psnr_db": float(np.mean([r[1] for r in rows])),
        "ssim": float(np.mean([r[2] for r in rows])),
        "lpips": float(np.mean([r[3] for r in rows])),
        # the design runs' task loss (L1 + LPIPS, iq-software and low light), what fine-tuning minimizes
        "l1_plus_lpips": float(np.mean([r[4] + r[3] for r in rows])),
        "psnr_db_photos": float(np.mean([r[1] for r in photo])) if photo else None,
        "psnr_db_procedural": float(np.mean([r[1] for r in proc])) if proc else None,
        "n_samples": len(rows),
    }
    parts = ", ".join(f"{k} {res[key][f'psnr_db_{k}']:.2f}" for k in ("photos", "procedural") if proc and photo)
    print(
        f"{key}: PSNR {res[key]['psnr_db']:.2f} dB{f' ({parts})' if parts else ''}, SSIM {res[key]['ssim']:.3f}, LPIPS {res[key]['lpips']:.4f}",
        flush=True,
    )


def _row(name: str, out: torch.Tensor, target: torch.Tensor) -> tuple[str, float, float, float, float]:
    """(name, PSNR, SSIM, LPIPS, L1) of the 8-bit output."""
    x = (out.clamp(0, 1) * 255).round() / 255
    y = target[None]
    return name, float(psnr(x, y)[0]), float(ssim(x, y)[0]), float(lpips(x, y)[0]), float((x - y).abs().mean())


def main(argv=None) -> dict:
    try:
        return _main(argv)
    except InputError as err:  # a missing checkpoint, a corpus of the wrong split: its one line
        raise SystemExit(str(err)) from None


def _main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("runs/isp_headroom"))
    ap.add_argument("--isp", action="append", default=None, help="software ISP checkpoint(s) (default: shipped)")
    ap.add_argument("--surrogate", default="paper-triplet-e2e")
    ap.add_argument("--size", type=int, default=192, help="held-out crop (the quick budget's)")
    ap.add_argument("--procedural", type=int, default=13)
    ap.add_argument("--photos", action="append", default=None, help="prepared photo corpus folder(s)")
    ap.add_argument("--split", choices=("val", "test"), default="val", help="with --photos: which split")
    ap.add_argument("--threads", type=int, default=0)
    a = ap.parse_args(argv)
    for path in a.isp or []:  # every checkpoint readable before minutes of work
        SoftwareISP.load(path)
    if a.threads:
        torch.set_num_threads(a.threads)
    a.out.mkdir(parents=True, exist_ok=True)
    frame = SensorFrame()
    sur = load_surrogate(a.surrogate, 5.86)
    f_number = base_lens_f_number(sur)
    from optix_e2e.dataset.manifest import space_and_base

    space, base = space_and_base(sur.manifest)
    nominal = np.asarray(space.values(base.data), float)
    ex = exact_optics(sur, nominal[None])
    psf, vig = torch.as_tensor(ex["psf"][0]).float(), torch.as_tensor(ex["vignetting"][0]).float()
    heights = design_field_heights(sur, nominal, ex["image_distance"][0])
    k, c, s = psf.shape[:3]
    lenses = {
        "perfect": PerfectOptics(s, full_field_px=frame.full_field_px),
        "nominal": FixedOptics(psf, vig, heights, full_field_px=frame.full_field_px),
    }
    if a.photos:
        corpus = PhotoCorpus(a.photos, a.split)
        samples = photo_test_set(corpus, a.size, s // 2, 0.7, frame, positions=POSITIONS["frame"])
    else:
        samples = heldout_set(a.size, s // 2, a.procedural, 0.7, frame, positions=POSITIONS["frame"])
    isps = {"classical": None} | {str(p): Path(p) for p in (a.isp or [SOFTWARE_ISP])}
    res, t0 = {}, time.time()
    m = s // 2
    for light, (ef, gf) in {"normal": (1.0, 1.0), "low": (0.01, 100.0)}.items():
        preset = calibrated_preset("imx249", f_number, ef, gf)
        classical = ClassicalISP(preset)
        bounds = {"no-cfa": [], "classical-noise-free": []}
        with torch.no_grad():
            for smp in tqdm(samples, desc=f"{light} bounds", leave=False):
                inner = smp.scene[:, m:-m, m:-m]
                bounds["no-cfa"].append(
                    _row(smp.name, _no_cfa(inner, preset, classical.to_linear, smp.noise_seed), smp.target)
                )
                clean = simulate_raw(inner[None], preset, noise=False)
                bounds["classical-noise-free"].append(_row(smp.name, classical(clean), smp.target))
        for bound, rows in bounds.items():
            _score(rows, f"{light}/bound/{bound}/perfect", res)
        for name, path in isps.items():
            stage = _Classical(preset) if path is None else SoftwareISPStage(SoftwareISP.load(path), preset)
            for lens, optics in lenses.items():
                cam = Camera(optics, SensorStage(preset), stage)
                rows = []
                with torch.no_grad():
                    for smp in tqdm(samples, desc=f"{light} {Path(name).name} {lens}", leave=False):
                        out, _ = cam(
                            smp.scene[None], smp.offset_px, torch.Generator().manual_seed(smp.noise_seed), final=True
                        )
                        rows.append(_row(smp.name, out, smp.target))
                _score(rows, f"{light}/{Path(name).name if path else name}/{lens}", res)
    out = {
        "held_out": {
            "set": corpus.record() if a.photos else "the design runs' held-out set (development set)",
            "n_images": len({s.name for s in samples}),
            "n_samples": len(samples),
            "size_px": a.size,
            "level": 0.7,
        },
        "surrogate": a.surrogate,
        "results": res,
        "wall_s": round(time.time() - t0, 1),
    }
    (a.out / "headroom.json").write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
