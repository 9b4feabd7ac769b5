"""The parts of ``method="auto"`` that span more than one PSF: how many wavelengths each
colour channel needs (from the lens's chromatic spread) and how many field samples K
(from how fast the PSF changes across the field).  The per-PSF choice of method and
sampling is the engine's (crates/psf-engine/src/psf/auto.rs).

Both are measured on pilot lenses (the base lens and a few designs of a space), with the
fast FFT, and the most demanding pilot decides:

* Wavelengths per channel: each channel's band is integrated by the midpoint rule
  (``accuracy.sweep.channel_wavelengths``), whose nodes nest: the 1-node rule's node is
  one of the 3-node rule's, whose nodes are among the 9-node rule's.  The PSFs at the 9
  nodes give the 1- and 3-node channel PSFs for free, and their relative L1 against the
  9-node PSF estimates their error (the rule's error falls as 1/k^2, so 9 nodes are within
  ~1/9 of the 3-node error; 5 nodes are predicted at (3/5)^2 of it).
* Field samples: PSFs at 33 fields from the axis to the full field; K samples are judged
  by the mean relative L1 of the linear interpolation between them at the other fields.
"""

from __future__ import annotations

import numpy as np

from .psf_errors import rel_l1
from .sweep import CHANNEL_RESPONSE, channel_wavelengths

#: Wavelengths-per-channel choices (nested midpoint rules, and 5 predicted from 3).
K_WAVELENGTHS = (1, 3, 5, 9)
#: Field-sample choices and the dense field grid they are judged on (where none meets the
#: target, the dense grid itself is used, and said).
K_FIELDS = (5, 7, 9, 13, 17, 25)
DENSE_FIELDS = 33


def _batch(lens_jsons, fields, channels, size, pixel_um):
    from .. import engine

    r = engine.psf_batch(
        lens_jsons,
        fields_deg=fields,
        channels=channels,
        method="fft",
        pixel_um=pixel_um,
        size=size,
        pupil_samples=64,
        aiming="paraxial",
        integrate=False,
        fast=True,
    )
    return r["psf"].astype(np.float64), r["ok"]


def choose_wavelengths(
    lens_jsons, max_field_deg: float, target: float, *, size: int = 128, pixel_um: float = 1.0
) -> dict:
    """Per channel of ``CHANNEL_RESPONSE``: the fewest midpoint wavelengths whose channel
    PSF is estimated within ``target`` (relative L1) at the axis, 0.7 and full field of
    every pilot lens.  Returns {channel: {"k", "estimated_rel_l1" {k: worst estimate},
    "wavelengths" [(nm, weight)]}}."""
    fields = [0.0, 0.7 * max_field_deg, max_field_deg]
    out = {}
    for name in CHANNEL_RESPONSE:
        nodes = channel_wavelengths(name, 9)
        psf, ok = _batch(lens_jsons, fields, [[p] for p in nodes], size, pixel_um)
        psf = psf[ok]  # (D, F, 9, S, S), unit sums
        w9 = np.array([w for _, w in nodes])
        p9 = np.einsum("dfkij,k->dfij", psf, w9)
        w3 = np.array([w for _, w in channel_wavelengths(name, 3)])
        p3 = np.einsum("dfkij,k->dfij", psf[:, :, [1, 4, 7]], w3)
        p1 = psf[:, :, 4]
        e1 = max(rel_l1(a, b) for a, b in zip(p1.reshape(-1, size, size), p9.reshape(-1, size, size)))
        e3 = max(rel_l1(a, b) for a, b in zip(p3.reshape(-1, size, size), p9.reshape(-1, size, size)))
        # (against the 9-node PSF, whose own error is ~e3 / 9: add it back to be safe)
        est = {1: e1 + e3 / 9, 3: e3 * 10 / 9, 5: e3 * 9 / 25 + e3 / 9, 9: e3 / 9}
        k = next((k for k in K_WAVELENGTHS if est[k] <= target), 9)
        out[name] = {
            "k": k,
            "estimated_rel_l1": {str(q): float(v) for q, v in est.items()},
            "wavelengths": channel_wavelengths(name, k),
        }
    return out


def choose_fields(
    lens_jsons, max_field_deg: float, wavelength_nm: float, target: float, *, size: int = 128, pixel_um: float = 1.0
) -> dict:
    """The fewest field samples K (of ``K_FIELDS``, uniform from the axis to the full field)
    whose linear interpolation reproduces the PSFs at ``DENSE_FIELDS`` fields within
    ``target`` mean relative L1, for every pilot lens; where none does, K = DENSE_FIELDS
    and "met" False.  Returns {"K", "mean_rel_l1" {K: worst pilot's mean}, "met"}."""
    dense = np.linspace(0.0, max_field_deg, DENSE_FIELDS)
    psf, ok = _batch(lens_jsons, dense, [[(float(wavelength_nm), 1.0)]], size, pixel_um)
    psf = psf[ok][:, :, 0]  # (D, F, S, S)
    errs = {}
    for k in K_FIELDS:
        idx = np.round(np.linspace(0, DENSE_FIELDS - 1, k)).astype(int)
        worst = 0.0
        for p in psf:
            e = []
            for j in range(DENSE_FIELDS):
                if j in idx:
                    continue
                hi = int(np.searchsorted(idx, j))
                a, b = idx[hi - 1], idx[hi]
                t = (j - a) / (b - a)
                e.append(rel_l1((1 - t) * p[a] + t * p[b], p[j]))
            worst = max(worst, float(np.mean(e)) if e else 0.0)
        errs[k] = worst
    k = next((k for k in K_FIELDS if errs[k] <= target), None)
    return {"K": k or DENSE_FIELDS, "mean_rel_l1": {str(q): v for q, v in errs.items()}, "met": k is not None}
