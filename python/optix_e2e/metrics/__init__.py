"""Image-quality metrics, all offline: PSNR, SSIM, HaarPSI (:mod:`.image`) and LPIPS
(AlexNet, v0.1; :mod:`.lpips`)."""

from .image import haarpsi, psnr, ssim, summarize

__all__ = ["psnr", "ssim", "haarpsi", "summarize"]
