"""The exact engine on the surrogate's terms: PSFs, vignetting and RMS spots of designs given
by their parameter values, computed exactly as the training dataset's were (same base lens,
apertures, refocusing, fields, channels, methods), so a surrogate prediction or a render
through it can be checked against the real optics."""

from __future__ import annotations

import numpy as np

from ..dataset.manifest import refocused_designs, space_and_base
from ..dataset.shards import compute_shard
from ..errors import InputError
from ..lens import Lens


class EngineRejectedDesign(InputError):
    """The engine cannot compute the design (or a neighbour a derivative needs); the message
    names the parameter values (or the parameter) and the engine's reason."""


def exact_arrays(manifest: dict, values) -> tuple[dict, dict]:
    """The dataset record (arrays as in a shard: psf, psf_sensor, relative_illumination,
    image_distance, ...) of the designs ``values`` [N, P]; designs the engine rejects are
    listed in the metadata's ``failures`` and missing from the arrays."""
    values = np.atleast_2d(np.asarray(values, np.float64))
    space, base = space_and_base(manifest)
    man = {**manifest, "settings": {**manifest["settings"], "shard_size": len(values)}, "n_designs": len(values)}
    arrays, meta = compute_shard(0, man, values, space, base)
    return arrays, meta


def exact_optics(surrogate, values, fallback: str | None = None) -> dict:
    """What the renderer needs from the engine for designs ``values`` [N, P] on a surrogate's
    terms: ``psf`` [N, K, C, S, S] (the surrogate's PSF kind and binning), ``vignetting``
    [N, K, C], the refocused ``image_distance`` (mm, N) and ``energy_in_window`` [N, K, C] (the
    fraction of the transmitted flux inside the PSF window: the PSFs are normalized over the
    window, so what falls outside is left out), and ``methods`` [N] (the PSF method used).
    A design the engine rejects is an error, unless ``fallback="huygens"``: then its PSFs are
    computed again by the Huygens method (the reference, where the FFT's pupil is too
    distorted for its window, as in fast, aberrated designs), and ``methods`` says so."""
    import torch

    from .data import bin_psf

    values = np.atleast_2d(np.asarray(values, np.float64))
    arrays, meta = exact_arrays(surrogate.manifest, values)
    methods = [surrogate.manifest["settings"].get("psf_method", "fft")] * len(values)
    if meta["n_failed"]:
        if fallback != "huygens":
            raise InputError(f"engine rejected the design: {meta['failures'][0]['reason']}")
        failed = sorted(int(f["design"]) for f in meta["failures"])
        # the same sensor-pitch PSFs from point samples at 2 um where the dataset's are finer
        # (a quarter of the cost; the Huygens PSF is smooth where the FFT fails: aberrated)
        st = surrogate.manifest["settings"]
        man = {
            **surrogate.manifest,
            "settings": {**st, "psf_method": "huygens", "pixel_um": max(float(st["pixel_um"]), 2.0)},
        }
        redo, meta2 = exact_arrays(man, values[failed])
        if meta2["n_failed"]:
            raise InputError(f"engine rejected the design (Huygens too): {meta2['failures'][0]['reason']}")
        ok = [i for i in range(len(values)) if i not in failed]
        merged = {}
        for k in (surrogate.psf_kind, "relative_illumination", "image_distance", "energy_in_window"):
            rows = {i: arrays[k][j] for j, i in enumerate(ok)} | {i: redo[k][j] for j, i in enumerate(failed)}
            merged[k] = np.stack([rows[i] for i in range(len(values))])
        arrays = merged
        for i in failed:
            methods[i] = "huygens"
    psf = torch.stack([bin_psf(torch.as_tensor(p), surrogate.bin) for p in arrays[surrogate.psf_kind]]).float()
    return {
        "psf": psf,
        "vignetting": torch.as_tensor(arrays["relative_illumination"], dtype=torch.float32),
        "image_distance": [float(z) for z in arrays["image_distance"]],
        "energy_in_window": np.asarray(arrays["energy_in_window"], np.float64),
        "methods": methods,
    }


def rms_spot_um(manifest: dict, values, rings: int = 32) -> np.ndarray:
    """Polychromatic RMS spot radius (um, centroid-referenced, over the lens's wavelengths and
    weights) of each design [N, K] at the dataset's K fields, after the dataset's refocusing."""
    arrays, meta = exact_arrays(manifest, values)
    if meta["n_failed"]:
        raise InputError("engine rejected designs: " + "; ".join(f["reason"] for f in meta["failures"]))
    out = []
    for d in refocused_designs(manifest, arrays["params"], arrays["image_distance"]):
        lens = Lens(d)
        out.append([lens.spot(f, rings=rings)["rms_um"] for f in manifest["fields_deg"]])
    return np.asarray(out, float)
