"""Differentiable Poisson sampling.

The forward value is an exact Poisson draw k ~ Poisson(mu) (torch.poisson, optional
torch.Generator). Poisson samples are integers, so d k / d mu needs an estimator:

``estimator="gaussian"`` (default): moment-matched pathwise gradient. Write the sample as
k = mu + sqrt(mu) * eps with the standardised residual eps = (k - mu) / sqrt(mu) held fixed
(the reparameterisation of the Gaussian with the Poisson's mean and variance). Then

    d k / d mu = 1 + (k - mu) / (2 mu),

which makes the gradient of E[f(k)] exact for every f of degree <= 2, because the Poisson's
first two moments E[k] = mu and E[k^2] = mu + mu^2 match the Gaussian's:
    f(k) = k:    E[1 + (k - mu)/(2 mu)]           = 1          = d mu / d mu
    f(k) = k^2:  E[2k (1 + (k - mu)/(2 mu))]      = 2 mu + 1   = d (mu + mu^2) / d mu
For higher-order f it is biased by O(1) (k^3: 3mu^2 + 6mu + 1.5 instead of 3mu^2 + 6mu + 1).
Below ``min_rate`` the (k - mu)/(2 mu) term, whose variance grows as 1/mu, is dropped, leaving the
straight-through gradient 1: still exact for the mean, bounded for dark pixels.

``estimator="straight_through"``: d k / d mu = 1 (exact for the mean only; E[k^2] gets 2mu).
"""

from __future__ import annotations

import torch
from ..errors import InputError

ESTIMATORS = ("gaussian", "straight_through")


def pathwise(rate: torch.Tensor, eps: torch.Tensor, min_rate: float = 1.0) -> torch.Tensor:
    """Deterministic part of the estimator: rate + sqrt(max(rate, min_rate)) * eps (eps held fixed)."""
    return rate + torch.sqrt(rate.clamp_min(min_rate)) * eps


def poisson_sample(
    rate: torch.Tensor, *, generator: torch.Generator | None = None, estimator: str = "gaussian", min_rate: float = 1.0
) -> torch.Tensor:
    """k ~ Poisson(rate) elementwise (same shape and dtype), differentiable w.r.t. rate (see module doc).

    Negative rates are treated as 0. The returned values are exactly the integer draws. A
    ``generator`` draws on its own device (a CPU one: the CPU's draws, whatever the rate's device).
    """
    if estimator not in ESTIMATORS:
        raise InputError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    mu = rate.detach().clamp_min(0)
    if generator is None:
        k = torch.poisson(mu)
    else:
        k = torch.poisson(mu.to(generator.device), generator=generator).to(mu.device)
    if not rate.requires_grad:
        return k
    if estimator == "straight_through":
        return k + (rate - rate.detach())
    eps = (k - mu) / torch.sqrt(mu.clamp_min(min_rate))
    g = pathwise(rate, eps, min_rate)
    return k + (g - g.detach())
