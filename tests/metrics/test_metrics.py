"""PSNR / SSIM / HaarPSI wrappers and the perceptual losses."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from optix_e2e.metrics import image as M
from optix_e2e.scenes import load_photo

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def photo() -> torch.Tensor:
    return load_photo("astronaut", 96)


def _noisy(img: torch.Tensor, sigma: float, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (img + sigma * torch.randn(img.shape, generator=g)).clamp(0, 1)


def _blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    r = math.ceil(3 * sigma)
    k = torch.exp(-(torch.arange(-r, r + 1.0) ** 2) / (2 * sigma**2))
    k = (k / k.sum()).view(1, 1, 1, -1).repeat(3, 1, 1, 1)
    x = F.pad(img[None], (r, r, r, r), mode="reflect")
    x = F.conv2d(F.conv2d(x, k, groups=3), k.transpose(2, 3), groups=3)
    return x[0]


def test_psnr_hand_calculation():
    x = torch.full((2, 3, 8, 8), 0.3)
    y = x + torch.tensor([0.1, 0.01]).view(2, 1, 1, 1)  # MSE 1e-2 and 1e-4
    assert M.psnr(x, y).tolist() == pytest.approx([20.0, 40.0], abs=1e-3)
    assert M.psnr(x * 255, y * 255, data_range=255.0).tolist() == pytest.approx([20.0, 40.0], abs=1e-3)
    assert M.psnr(x[0], y[0]).shape == ()  # unbatched in, 0-d out
    assert M.psnr(x, x).isinf().all()
    # only the 1-pixel border differs: crop=1 ignores it
    z = x.clone()
    z[..., 0, :] = 1.0
    assert math.isfinite(M.psnr(x, z)[0]) and M.psnr(x, z, crop=1).isinf().all()


def test_ssim_identity_monotone_and_matches_skimage(photo):
    from skimage.metrics import structural_similarity

    assert M.ssim(photo, photo).item() == pytest.approx(1.0, abs=1e-6)
    scores = [M.ssim(photo, _noisy(photo, s)).item() for s in (0.01, 0.03, 0.1, 0.3)]
    assert all(a > b for a, b in zip(scores, scores[1:])), scores
    y = _noisy(photo, 0.05)
    ref = structural_similarity(
        photo.permute(1, 2, 0).numpy(),
        y.permute(1, 2, 0).numpy(),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=2,
    )
    assert M.ssim(photo, y).item() == pytest.approx(ref, abs=1e-4)
    batch = M.ssim(torch.stack([photo, photo]), torch.stack([photo, y]))
    assert batch.shape == (2,) and batch[0] > batch[1]


def test_haarpsi_identity_and_monotone_in_noise_and_blur(photo):
    assert M.haarpsi(photo, photo).item() == pytest.approx(1.0, abs=1e-4)
    assert M.perceptual_distance(photo, photo).item() == pytest.approx(0.0, abs=1e-4)
    noise = [M.haarpsi(photo, _noisy(photo, s)).item() for s in (0.01, 0.03, 0.1, 0.3)]
    blur = [M.haarpsi(photo, _blur(photo, s)).item() for s in (0.5, 1.0, 2.0, 4.0)]
    for seq in (noise, blur):
        assert all(a > b for a, b in zip(seq, seq[1:])), seq
        assert seq[0] < 1.0 and seq[-1] > 0.0
    d = M.perceptual_distance(photo, _blur(photo, 1.0))
    assert d.item() == pytest.approx(1.0 - blur[1], abs=1e-6)


def test_small_or_mismatched_images_raise_clear_errors():
    with pytest.raises(ValueError, match="at least 16x16"):
        M.haarpsi(torch.rand(3, 12, 40), torch.rand(3, 12, 40))
    with pytest.raises(ValueError, match="at least 11x11"):
        M.ssim(torch.rand(3, 8, 8), torch.rand(3, 8, 8))
    with pytest.raises(ValueError, match="differ in shape"):
        M.psnr(torch.rand(3, 8, 8), torch.rand(3, 8, 9))
    with pytest.raises(ValueError, match="crop"):
        M.psnr(torch.rand(3, 8, 8), torch.rand(3, 8, 8), crop=4)


def test_perceptual_loss_gradients_and_descent(photo):
    target = photo[None, :, :64, :64]
    x = _noisy(target, 0.1, seed=1).requires_grad_(True)
    loss_fn = M.PerceptualLoss()
    opt = torch.optim.Adam([x], lr=0.01)
    first = None
    for _ in range(10):
        opt.zero_grad()
        loss = loss_fn(x, target)
        loss.backward()
        assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
        first = loss.item() if first is None else first
        opt.step()
    assert loss_fn(x, target).item() < 0.8 * first


def test_out_of_range_inputs_are_clamped_with_straight_through_gradient(photo):
    target = photo[None, :, :32, :32]
    x = target.clone()
    x[..., 5, 5] = 1.5
    x[..., 9, 9] = -0.5
    x.requires_grad_(True)
    assert M.haarpsi(x, target).item() == pytest.approx(M.haarpsi(x.detach().clamp(0, 1), target).item())
    M.L1PerceptualLoss(weight=1.0)(x, target).backward()
    assert torch.isfinite(x.grad).all()
    assert (x.grad[..., 5, 5] > 0).all() and (x.grad[..., 9, 9] < 0).all()  # pulled back in range
    M.ssim(x, target)  # no assertion error from piq's range check


def test_l1_perceptual_loss_and_summarize(photo):
    y = _noisy(photo, 0.05)
    xb, yb = photo[None], y[None]
    l1 = (xb - yb).abs().mean()
    assert M.L1PerceptualLoss(weight=0.0)(xb, yb).item() == pytest.approx(l1.item())
    w = 0.5
    want = l1 + w * M.perceptual_distance(xb, yb).mean()
    assert M.L1PerceptualLoss(weight=w)(xb, yb).item() == pytest.approx(want.item(), rel=1e-6)
    s = M.summarize(xb, yb)
    assert set(s) == {"psnr_db", "ssim", "haarpsi"} and all(isinstance(v, float) for v in s.values())
    assert s["psnr_db"] == pytest.approx(M.psnr(photo, y).item())
    assert 0 < s["ssim"] < 1 and 0 < s["haarpsi"] < 1
