"""Refining a surrogate around one design: engine data sampled in a small box about the
design (the exact optics of optics/exact.py, a few hundred designs in one parallel call), then
a short fine-tune of the network on it with the training loss (Eq. 8). A trust-region
surrogate: accurate where the optimizer is, whatever it has forgotten far away.

The hybrid design runs (camera_design/hybrid.py) call it when the surrogate's error at the current
design passes a threshold.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from .loss import LossWeights, optics_loss_terms


@dataclass(frozen=True)
class RefineSettings:
    designs: int = 192  # engine designs sampled about the design (plus the design itself)
    radius: float = 0.02  # half-width of the box, as a fraction of each parameter's range
    steps: int = 150  # Adam steps of the fine-tune
    batch: int = 64  # (design, field) samples per step; a quarter from the centre design
    lr: float = 3e-4
    seed: int = 0

    def to_json(self) -> dict:
        return asdict(self)


def local_designs(
    values: np.ndarray, lo: np.ndarray, hi: np.ndarray, n: int, radius: float, rng: np.random.Generator
) -> np.ndarray:
    """``n`` designs uniform in the box values +- radius * (hi - lo), clipped into the ranges."""
    width = hi - lo
    d = values[None] + radius * width[None] * rng.uniform(-1.0, 1.0, (n, len(values)))
    return np.clip(d, lo, hi)


def field_errors(sur, values: np.ndarray, psf_true: torch.Tensor) -> list[float]:
    """The surrogate's PSF relative L1 per field at ``values`` (median over channels)."""
    with torch.no_grad():
        psf, _ = sur.psfs(torch.as_tensor(values, dtype=torch.float32, device=sur.param_mean.device), check=False)
    err = (psf.double() - psf_true.double().to(psf.device)).abs().sum((-2, -1))
    return [float(x) for x in err.median(dim=1).values]


def refine_around(sur, engine, values, settings: RefineSettings = RefineSettings()) -> dict:
    """Fine-tune ``sur`` (in place) on engine data about ``values`` [P]; returns what it did:
    designs computed and rejected, steps, seconds, and the per-field error at the design
    before and after."""
    t0 = time.perf_counter()
    v = np.asarray(values, np.float64).reshape(-1)
    lo, hi = engine._range()
    rng = np.random.default_rng([11, settings.seed])
    designs = np.concatenate([v[None], local_designs(v, lo, hi, settings.designs, settings.radius, rng)])
    psf, vig, _ = engine._run(designs)
    ok = [i for i, p in enumerate(psf) if p is not None]
    if 0 not in ok:
        from .ground_truth import EngineRejectedDesign

        raise EngineRejectedDesign("cannot refine the surrogate: the engine rejects the current design")
    dev = sur.param_mean.device  # the engine's data go to the surrogate's device once
    params = torch.as_tensor(designs[ok], dtype=torch.float32, device=dev)
    psf_t = torch.as_tensor(np.stack([psf[i] for i in ok]), dtype=torch.float32, device=dev)  # [N, K, C, S, S]
    vig_t = torch.as_tensor(np.stack([vig[i] for i in ok]), dtype=torch.float32, device=dev)  # [N, K, C]
    before = field_errors(sur, v, psf_t[0])
    net = sur.net
    was = [p.requires_grad for p in net.parameters()]
    for p in net.parameters():
        p.requires_grad_(True)
    opt = torch.optim.Adam(net.parameters(), lr=settings.lr)
    gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
    n, k = len(ok), len(sur.fields_deg)
    weights = LossWeights()
    net.train()
    try:
        for _ in range(settings.steps):
            d = torch.randint(n, (settings.batch,), generator=gen)
            d[: settings.batch // 4] = 0  # the design itself, every step
            f = torch.randint(k, (settings.batch,), generator=gen)
            d, f = d.to(dev), f.to(dev)  # drawn on the CPU: the same draws on any device
            p, g = net(sur.normalize(params[d]), sur.fields[f])
            loss = weights.total(optics_loss_terms(p, g, psf_t[d, f], vig_t[d, f]))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
    finally:
        net.eval()
        for p, r in zip(net.parameters(), was):
            p.requires_grad_(r)
            p.grad = None
    after = field_errors(sur, v, psf_t[0])
    return {
        "designs": len(designs),
        "rejected": len(designs) - n,
        "steps": settings.steps,
        "seconds": time.perf_counter() - t0,
        "error_before": before,
        "error_after": after,
    }
