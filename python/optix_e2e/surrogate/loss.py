"""The surrogate's training loss, paper Eq. 8:

    L = L1(psf, psf*) + L1(F psf, F psf*) + sum_d L1(grad_d psf, grad_d psf*) + L1(v, v*)

on the energy-preserving (unit-sum) PSFs and the vignetting factors. Each PSF term sums
over a PSF's pixels (frequencies) and averages over samples and channels, so the first term
is exactly the relative L1 error of unit-sum PSFs that the evaluation reports; the Fourier
term uses the unnormalized DFT (its DC term is 1 for both), averaged over frequencies; the
vignetting term averages over samples and channels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from ..errors import InputError


@dataclass(frozen=True)
class LossWeights:
    pixel: float = 1.0
    fourier: float = 1.0
    gradient: float = 1.0
    vignetting: float = 1.0

    def to_json(self) -> dict:
        return asdict(self)

    def total(self, terms: dict[str, torch.Tensor]) -> torch.Tensor:
        """The weighted sum of :func:`optics_loss_terms`."""
        return (
            self.pixel * terms["pixel"]
            + self.fourier * terms["fourier"]
            + self.gradient * terms["gradient"]
            + self.vignetting * terms["vignetting"]
        )


def optics_loss_terms(
    psf: torch.Tensor, vignetting: torch.Tensor, psf_true: torch.Tensor, vignetting_true: torch.Tensor
) -> dict[str, torch.Tensor]:
    """The four terms of Eq. 8 (scalars). psf, psf_true [B, C, S, S]; vignetting [B, C]."""
    if psf.shape != psf_true.shape or vignetting.shape != vignetting_true.shape:
        raise InputError(
            f"shape mismatch: psf {list(psf.shape)} vs {list(psf_true.shape)}, "
            f"vignetting {list(vignetting.shape)} vs {list(vignetting_true.shape)}"
        )
    d = psf - psf_true
    pixel = d.abs().sum((-2, -1)).mean()
    fourier = (torch.fft.fft2(psf) - torch.fft.fft2(psf_true)).abs().mean()
    gradient = (
        (d[..., 1:, :] - d[..., :-1, :]).abs().sum((-2, -1)) + (d[..., :, 1:] - d[..., :, :-1]).abs().sum((-2, -1))
    ).mean()
    vig = (vignetting - vignetting_true).abs().mean()
    return {"pixel": pixel, "fourier": fourier, "gradient": gradient, "vignetting": vig}


def optics_loss(psf, vignetting, psf_true, vignetting_true, weights: LossWeights = LossWeights()) -> torch.Tensor:
    """Eq. 8 as one scalar (weights 1 as in the paper)."""
    return weights.total(optics_loss_terms(psf, vignetting, psf_true, vignetting_true))


class OpticsLoss(nn.Module):
    """Module twin of :func:`optics_loss`."""

    def __init__(self, weights: LossWeights = LossWeights()):
        super().__init__()
        self.weights = weights

    def forward(self, psf, vignetting, psf_true, vignetting_true) -> torch.Tensor:
        return optics_loss(psf, vignetting, psf_true, vignetting_true, self.weights)
