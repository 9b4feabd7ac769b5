"""Image-quality metrics that run fully offline: PSNR, SSIM and HaarPSI.

Inputs are torch tensors [B,3,H,W] or [3,H,W], sRGB-encoded in [0,1]; every metric returns
one value per image ([B], or a 0-d tensor for an unbatched image).  ``crop`` drops that
many pixels from every border first (the usual way to keep demosaicking/convolution
borders out of a score).

Why HaarPSI is the perceptual metric
------------------------------------
The learned perceptual metrics (LPIPS, DISTS, PieAPP) need network weights that their
libraries download on first use (LPIPS also an ImageNet VGG/AlexNet backbone from
torchvision); this toolkit must run without network access.  LPIPS (AlexNet, v0.1), the
paper's metric, is available offline from weights installed with the project
(optix_e2e.metrics.lpips, reproducing the original's distances); it is reported beside these, and
HaarPSI stays the training loss's perceptual term.  HaarPSI
(Reisenhofer, Bosse, Kutyniok & Wiegand, "A Haar wavelet-based perceptual similarity index
for image quality assessment", Signal Processing: Image Communication 61, 2018) is a
closed-form index: local similarities of Haar-wavelet responses (luminance, plus the YIQ
chroma channels) weighted by a wavelet-based saliency map.  It has no weights, it is
differentiable (piq implements it in pure torch), and on the standard subjective-quality
databases it agrees with human opinion at least as well as LPIPS: piq's benchmark (SRCC
with mean opinion scores, piq 0.8 README) gives HaarPSI 0.87 on TID2013 and 0.89 on
KADID-10k against 0.67 / 0.72 for LPIPS-VGG and 0.81 / 0.88 for DISTS (PSNR 0.69 / 0.68,
SSIM 0.72 / 0.72).  The distortions of those databases (blur, noise, compression, colour
and contrast shifts) are the ones a camera pipeline makes.  Its weakness: on PIPAL (GAN
and restoration artefacts) it scores 0.59, like LPIPS (0.57) but below DISTS (0.62) and
PieAPP (0.70), so hallucinated texture is judged less reliably.

HaarPSI averages the images 2x2 before analysis (the paper's default, modelling viewing
distance) and needs at least 16x16 pixels.  piq rejects values outside [0,1], so HaarPSI
and SSIM see inputs clamped with a straight-through gradient: the value is clamped, the
gradient passes as if it were not, so out-of-range pixels still get pulled back by the
loss.  PSNR uses the values as given.
"""

from __future__ import annotations

import piq
import torch
from torch import nn

from ..errors import InputError

__all__ = [
    "psnr",
    "ssim",
    "haarpsi",
    "perceptual_distance",
    "PerceptualLoss",
    "L1PerceptualLoss",
    "summarize",
    "HAARPSI_MIN_SIZE",
]

HAARPSI_MIN_SIZE = 16  # 2 ** (scales + 1) with piq's default scales=3
_SSIM_KERNEL = 11


def _prepare(x: torch.Tensor, y: torch.Tensor, crop: int) -> tuple[torch.Tensor, torch.Tensor, bool]:
    if x.shape != y.shape:
        raise InputError(f"images differ in shape: {tuple(x.shape)} vs {tuple(y.shape)}")
    if x.ndim not in (3, 4):
        raise InputError(f"expected [C,H,W] or [B,C,H,W], got shape {tuple(x.shape)}")
    single = x.ndim == 3
    if single:
        x, y = x[None], y[None]
    if crop:
        if 2 * crop >= min(x.shape[-2:]):
            raise InputError(f"crop={crop} removes the whole {x.shape[-2]}x{x.shape[-1]} image")
        x, y = x[..., crop:-crop, crop:-crop], y[..., crop:-crop, crop:-crop]
    return x, y, single


def _out(v: torch.Tensor, single: bool) -> torch.Tensor:
    return v[0] if single else v


def _clamp01(x: torch.Tensor) -> torch.Tensor:
    """Clamp to [0,1] in value, identity in gradient (straight-through)."""
    return x.clamp(0.0, 1.0) + (x - x.detach())


def psnr(x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0, crop: int = 0) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB, 10 log10(data_range^2 / MSE); inf for identical images."""
    x, y, single = _prepare(x, y, crop)
    mse = (x - y).pow(2).flatten(1).mean(1)
    return _out(10.0 * torch.log10(data_range**2 / mse), single)


def ssim(x: torch.Tensor, y: torch.Tensor, crop: int = 0, *, downsample: bool = False) -> torch.Tensor:
    """Structural similarity (Wang et al. 2004; 11x11 Gaussian window, sigma 1.5), mean over channels.

    ``downsample=False`` (default) scores at full resolution, which is where optical blur and
    demosaicking artefacts live; ``True`` first averages by round(min(H,W)/256) as in the
    authors' reference code.  Equals skimage's ``structural_similarity`` with
    ``gaussian_weights=True, use_sample_covariance=False``.
    """
    x, y, single = _prepare(x, y, crop)
    if min(x.shape[-2:]) < _SSIM_KERNEL:
        raise InputError(
            f"SSIM needs images of at least {_SSIM_KERNEL}x{_SSIM_KERNEL} pixels, got {x.shape[-2]}x{x.shape[-1]}"
        )
    v = piq.ssim(_clamp01(x), _clamp01(y), data_range=1.0, reduction="none", downsample=downsample)
    return _out(v, single)


def haarpsi(x: torch.Tensor, y: torch.Tensor, crop: int = 0) -> torch.Tensor:
    """HaarPSI similarity in (0, 1], 1 for identical images (higher is better)."""
    x, y, single = _prepare(x, y, crop)
    if min(x.shape[-2:]) < HAARPSI_MIN_SIZE:
        raise InputError(
            f"HaarPSI needs images of at least {HAARPSI_MIN_SIZE}x{HAARPSI_MIN_SIZE} "
            f"pixels, got {x.shape[-2]}x{x.shape[-1]}"
        )
    if x.shape[1] not in (1, 3):
        raise InputError(f"HaarPSI takes 1 or 3 channels, got {x.shape[1]}")
    score = piq.haarpsi(_clamp01(x), _clamp01(y), data_range=1.0, reduction="none")
    # Two images without any structure at HaarPSI's coarsest scale (black, both) weigh nothing:
    # piq's ratio is then eps / eps = 1 and its logit infinite. Such images are identical as far
    # as HaarPSI can see, so they score 1, as identical images do.
    return _out(torch.where(torch.isfinite(score), score, torch.ones_like(score)), single)


def perceptual_distance(x: torch.Tensor, y: torch.Tensor, crop: int = 0) -> torch.Tensor:
    """1 - HaarPSI: 0 for identical images, larger is worse."""
    return 1.0 - haarpsi(x, y, crop)


class PerceptualLoss(nn.Module):
    """Mean of 1 - HaarPSI over the batch; differentiable in both inputs."""

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return perceptual_distance(x, y).mean()


class L1PerceptualLoss(nn.Module):
    """Mean absolute error + ``weight`` * (1 - HaarPSI).  weight=1 is a starting point, not tuned."""

    def __init__(self, weight: float = 1.0):
        super().__init__()
        self.weight = float(weight)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        loss = (x - y).abs().mean()
        return loss + self.weight * perceptual_distance(x, y).mean() if self.weight else loss


@torch.no_grad()
def summarize(x: torch.Tensor, y: torch.Tensor, crop: int = 0) -> dict[str, float]:
    """Batch means as floats: {"psnr_db", "ssim", "haarpsi"} (psnr_db is inf if all identical)."""
    return {
        "psnr_db": float(psnr(x, y, crop=crop).mean()),
        "ssim": float(ssim(x, y, crop=crop).mean()),
        "haarpsi": float(haarpsi(x, y, crop=crop).mean()),
    }
