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


#: unit steps from the normal approximation's guess before the bisection takes over (one or two
#: suffice for the uniforms torch.rand draws, u >= 2^-53, at any rate a sensor holds)
QUANTILE_STEPS = 16


@torch.no_grad()
def poisson_quantile(u: torch.Tensor, rate: torch.Tensor) -> torch.Tensor:
    """The Poisson quantile: the smallest integer k >= 0 with P(K <= k) >= u, K ~ Poisson(rate),
    elementwise (float64, broadcast; rates < 0 taken as 0, u in [0, 1)). Not differentiable.

    What the common-random-number shot noise needs (the same uniform u gives nearby counts
    at nearby rates). The same values as ``scipy.stats.poisson.ppf`` (tests/sensor/test_poisson.py;
    scipy gives -1 at u = 0, this 0), in torch on the tensors' device and 5-20x faster on the
    CPU: from the Cornish-Fisher guess floor(rate + sqrt(rate) z + (z^2 - 1) / 6), z = Phi^-1(u),
    it steps up while P(K <= k) = Q(k + 1, rate) < u and down while P(K <= k - 1) = Q(k, rate)
    >= u (Q the regularized upper incomplete gamma function); an element still moving after
    ``QUANTILE_STEPS`` steps (u far in a tail) is bisected instead."""
    u, lam = torch.broadcast_tensors(u.double(), rate.double().clamp_min(0))
    if torch.any((u < 0) | (u >= 1) | torch.isnan(u)) or not torch.isfinite(lam).all():
        raise InputError("poisson_quantile needs u in [0, 1) and finite rates")
    z = torch.special.ndtri(u.clamp(min=2.0**-60))
    k = torch.floor(lam + lam.sqrt() * z + (z * z - 1.0) / 6.0).clamp_min(0.0)
    stuck = torch.zeros_like(u, dtype=torch.bool)
    for step in (1.0, -1.0):
        for _ in range(QUANTILE_STEPS + 1):
            if step > 0:
                move = torch.special.gammaincc(k + 1.0, lam) < u
            else:
                move = (k > 0) & (torch.special.gammaincc(k.clamp_min(1.0), lam) >= u)
            move &= ~stuck
            if not move.any():
                break
            k = k + step * move
        else:
            stuck |= move
    if stuck.any():
        k[stuck] = _bisected_quantile(u[stuck], lam[stuck])
    return k


def _bisected_quantile(u: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """``poisson_quantile`` by bisection over [0, rate + 40 sqrt(rate) + 100], where P(K <= k)
    rounds to 1 in float64."""
    lo = torch.full_like(lam, -1.0)  # P(K <= -1) = 0: below any u > 0 (u = 0 ends at k = 0)
    hi = torch.floor(lam + 40.0 * lam.sqrt() + 100.0)
    while torch.any(hi - lo > 1):
        mid = torch.floor((lo + hi) / 2)
        ok = torch.special.gammaincc(mid + 1.0, lam) >= u
        hi, lo = torch.where(ok, mid, hi), torch.where(ok, lo, mid)
    return hi
