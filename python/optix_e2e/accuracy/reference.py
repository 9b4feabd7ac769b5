"""The converged reference PSF: Huygens at increasing pupil sampling, doubled until two
successive results agree (docs/accuracy.md)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..errors import RunError
from .psf_errors import rel_l1


@dataclass
class Reference:
    psf: np.ndarray
    strehl: float | None
    pupil_samples: int
    #: relative L1 between the last two doublings (the reference's own error is about a
    #: third of it: Huygens' error falls ~4x per doubling)
    convergence: float
    seconds: float
    diagnostics: dict


def converged_reference(
    lens_json: str,
    field_deg: float,
    wavelength_nm: float,
    *,
    size: int,
    pixel_um: float,
    start: int = 128,
    tol: float = 5e-3,
    max_samples: int = 1024,
) -> Reference:
    """Huygens PSFs at ``start``, 2 ``start``, ... pupil samples until the relative L1
    between two successive ones is within ``tol``; returns the last.  Raises RuntimeError
    if ``max_samples`` is reached first."""
    from .. import engine

    t0 = time.perf_counter()
    prev, n, change = None, start, float("inf")
    while n <= max_samples:
        try:
            psf, diag = engine.psf(
                lens_json,
                field_deg=field_deg,
                wavelength_nm=wavelength_nm,
                method="huygens",
                pixel_um=pixel_um,
                size=size,
                pupil_samples=n,
            )
        except engine.PsfError:  # refused by its own checks (aliased at this sampling): not yet
            prev, n = None, 2 * n
            continue
        if prev is not None:
            change = rel_l1(prev, psf) if prev.sum() > 0 else float("inf")
            if change <= tol:
                return Reference(psf, diag.get("strehl"), n, change, time.perf_counter() - t0, diag)
        prev, n = psf, 2 * n
    raise RunError(
        f"Huygens reference at {field_deg} deg, {wavelength_nm} nm did not converge to "
        f"{tol:.1%} by {max_samples} pupil samples (last change {change:.2%})"
    )
