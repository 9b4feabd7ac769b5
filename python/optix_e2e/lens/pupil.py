"""Quadrature over the unit pupil disk, shared by the wavefront analysis (Lens.wavefront) and
the lens optimizer's merit functions."""

from __future__ import annotations

import numpy as np


def pupil_quadrature(rings: int, arms: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Legendre in rho^2 x uniform azimuths: points (px, py) and weights summing to 1
    such that sum w f(p) ~ mean of f over the unit pupil disk."""
    t, w = np.polynomial.legendre.leggauss(rings)
    t = 0.5 * (t + 1.0)  # rho^2 nodes in (0, 1)
    w = 0.5 * w
    theta = (np.arange(arms) + 0.5) * 2.0 * np.pi / arms
    rho = np.sqrt(t)[:, None]
    px = (rho * np.cos(theta)[None, :]).ravel()
    py = (rho * np.sin(theta)[None, :]).ravel()
    weights = np.repeat(w / arms, arms)
    return px, py, weights
