"""The exact engine on the surrogate's terms: PSFs, vignetting and RMS spots of designs given
by their parameter values, computed exactly as the training dataset's were (same base lens,
apertures, refocusing, fields, channels, methods), so a surrogate prediction or a render
through it can be checked against the real optics."""

from __future__ import annotations

import numpy as np

from ..dataset.generate import compute_shard
from ..dataset.manifest import refocused_designs, space_and_base
from ..lens import Lens


def exact_arrays(manifest: dict, values) -> tuple[dict, dict]:
    """The dataset record (arrays as in a shard: psf, psf_sensor, relative_illumination,
    image_distance, ...) of the designs ``values`` [N, P]; designs the engine rejects are
    listed in the metadata's ``failures`` and missing from the arrays."""
    values = np.atleast_2d(np.asarray(values, np.float64))
    space, base = space_and_base(manifest)
    man = {**manifest, "settings": {**manifest["settings"], "shard_size": len(values)}, "n_designs": len(values)}
    arrays, meta = compute_shard(0, man, values, space, base)
    return arrays, meta


def exact_optics(surrogate, values) -> dict:
    """What the renderer needs from the engine for designs ``values`` [N, P] on a surrogate's
    terms: ``psf`` [N, K, C, S, S] (the surrogate's PSF kind and binning), ``vignetting``
    [N, K, C], the refocused ``image_distance`` (mm, N) and ``energy_in_window`` [N, K, C] (the
    fraction of the transmitted flux inside the PSF window: the PSFs are normalized over the
    window, so what falls outside is left out); a rejected design is an error."""
    import torch

    from .data import bin_psf

    arrays, meta = exact_arrays(surrogate.manifest, np.atleast_2d(np.asarray(values, np.float64)))
    if meta["n_failed"]:
        raise ValueError(f"engine rejected the design: {meta['failures'][0]['reason']}")
    psf = torch.stack([bin_psf(torch.as_tensor(p), surrogate.bin) for p in arrays[surrogate.psf_kind]]).float()
    return {"psf": psf, "vignetting": torch.as_tensor(arrays["relative_illumination"], dtype=torch.float32),
            "image_distance": [float(z) for z in arrays["image_distance"]],
            "energy_in_window": np.asarray(arrays["energy_in_window"], np.float64)}


def rms_spot_um(manifest: dict, values, rings: int = 32) -> np.ndarray:
    """Polychromatic RMS spot radius (um, centroid-referenced, over the lens's wavelengths and
    weights) of each design [N, K] at the dataset's K fields, after the dataset's refocusing."""
    arrays, meta = exact_arrays(manifest, values)
    if meta["n_failed"]:
        raise ValueError("engine rejected designs: " + "; ".join(f["reason"] for f in meta["failures"]))
    out = []
    for d in refocused_designs(manifest, arrays["params"], arrays["image_distance"]):
        lens = Lens(d)
        out.append([lens.spot(f, rings=rings)["rms_um"] for f in manifest["fields_deg"]])
    return np.asarray(out, float)
