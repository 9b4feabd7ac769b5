"""Overlap-add spatially varying rendering (paper Eq. 2) against brute force and closed cases."""

from __future__ import annotations

import math

import pytest
import torch

from optix_e2e.optics.render import interpolate_fields, pixel_polar, psf_at, render, render_exact, rotate_psfs

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def comatic_stack(k: int = 5, s: int = 9, c: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """K PSFs [K, C, S, S] that grow and shift outward (+row) with the field: coma-like, asymmetric."""
    fields = torch.linspace(0, 1, k, dtype=torch.float64)
    y, x = torch.meshgrid(
        torch.arange(s, dtype=torch.float64) - s // 2, torch.arange(s, dtype=torch.float64) - s // 2, indexing="ij"
    )
    stack = []
    for f in fields:
        chans = []
        for ch in range(c):
            sy, sx = 0.6 + 1.6 * f + 0.2 * ch, 0.6 + 0.8 * f
            g = torch.exp(-0.5 * (((y - 1.5 * f) / sy) ** 2 + (x / sx) ** 2))
            chans.append(g / g.sum())
        stack.append(torch.stack(chans))
    return torch.stack(stack), fields


def test_rotation_points_the_outward_axis_along_the_azimuth():
    psf = torch.zeros(1, 1, 7, 7, dtype=torch.float64)
    psf[0, 0, 3 + 2, 3] = 1.0  # 2 px outward (+row)
    for az, (dy, dx) in ((0.0, (2, 0)), (math.pi / 2, (0, 2)), (math.pi, (-2, 0)), (-math.pi / 2, (0, -2))):
        out = rotate_psfs(psf, torch.tensor([az], dtype=torch.float64))[0, 0]
        iy, ix = divmod(int(out.argmax()), 7)
        assert (iy - 3, ix - 3) == (dy, dx), az
        assert out.sum().item() == pytest.approx(1.0)


def test_field_interpolation_is_linear_and_clamped():
    vals = torch.tensor([[0.0], [1.0], [3.0]], dtype=torch.float64)
    f = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    r = torch.tensor([0.0, 0.25, 0.75, 1.0, 1.5], dtype=torch.float64)
    assert interpolate_fields(vals, f, r)[:, 0].tolist() == pytest.approx([0.0, 0.5, 2.0, 3.0, 3.0])


def test_overlap_add_converges_to_brute_force_as_patches_shrink():
    torch.manual_seed(0)
    psfs, fields = comatic_stack()
    img = torch.rand(1, 3, 48, 40, dtype=torch.float64)
    exact = render_exact(img, psfs, fields)
    errs = []
    for p in (32, 16, 8):
        out = render(img, psfs, fields, patch=p)
        errs.append(((out - exact).abs().sum() / exact.abs().sum()).item())
    assert errs[0] > errs[1] > errs[2], errs
    assert errs[2] < 0.01, errs  # stated error: < 1% relative L1 at 8 px patches for this stack


def test_point_source_reproduces_the_interpolated_psf_at_its_position():
    # A point source spreads with the window-weighted blend of the PSFs of the patches around
    # it; the blend tends to the PSF at its own position as patches shrink. The error is
    # largest next to the axis, where the azimuth turns fastest and this sub-pixel PSF changes
    # fastest relative to its size.
    psfs, fields = comatic_stack()
    h, w = 64, 64
    full = 0.5 * math.hypot(h - 1, w - 1)
    for (py, px), tol in (((10, 50), 0.01), ((40, 12), 0.01), ((31, 33), 0.06)):
        dy, dx = py - (h - 1) / 2, px - (w - 1) / 2
        want = psf_at(
            psfs,
            fields,
            torch.tensor([math.hypot(dy, dx) / full], dtype=torch.float64),
            torch.tensor([math.atan2(dx, dy)], dtype=torch.float64),
        )[0]
        img = torch.zeros(1, 3, h, w, dtype=torch.float64)
        img[0, :, py, px] = 1.0
        errs = []
        for p in (16, 8, 4, 2):
            out = render(img, psfs, fields, patch=p)[0, :, py - 4 : py + 5, px - 4 : px + 5]
            errs.append(((out - want).abs().sum() / want.sum()).item())
        assert errs == sorted(errs, reverse=True), ((py, px), errs)
        assert errs[1 if tol < 0.05 else 3] < tol, ((py, px), errs)  # 8 px patches off axis, 2 px near it


def test_energy_is_conserved_and_vignetting_applied():
    psfs, fields = comatic_stack()
    img = torch.zeros(2, 3, 40, 40, dtype=torch.float64)
    img[:, :, 8:32, 8:32] = torch.rand(2, 3, 24, 24, dtype=torch.float64)  # margin wider than the PSF
    out = render(img, psfs, fields, patch=16)
    assert torch.allclose(out.sum((-2, -1)), img.sum((-2, -1)), rtol=1e-10)
    flat = torch.ones(1, 3, 40, 40, dtype=torch.float64)
    vig = torch.linspace(1.0, 0.5, 5, dtype=torch.float64)[:, None].expand(5, 3)
    delta = torch.zeros(5, 3, 9, 9, dtype=torch.float64)
    delta[:, :, 4, 4] = 1
    out = render(flat, delta, fields, vig, patch=16)[0, 0, 5:-5, 5:-5]  # away from the frame edge
    r, _ = pixel_polar(40, 40)
    want = interpolate_fields(vig[:, 0], fields, r.double().reshape(-1)).reshape(40, 40)[5:-5, 5:-5]
    assert (out - want).abs().max() < 0.01


def test_render_is_differentiable_in_psfs_and_vignetting():
    psfs, fields = comatic_stack(k=3, s=5, c=1)
    psfs = psfs.clone().requires_grad_(True)
    vig = torch.tensor([[1.0], [0.9], [0.7]], dtype=torch.float64, requires_grad=True)
    img = torch.rand(1, 1, 12, 10, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p, v: render(img, p, fields, v, patch=4), (psfs, vig))


def test_bad_inputs_are_named():
    psfs, fields = comatic_stack(k=3, s=5, c=1)
    with pytest.raises(ValueError, match="odd"):
        render(torch.zeros(1, 1, 8, 8), torch.zeros(3, 1, 4, 4), fields)
    with pytest.raises(ValueError, match="increasing"):
        render(torch.zeros(1, 1, 8, 8), psfs.float(), [0.0, 0.5, 0.2])
    with pytest.raises(ValueError, match="patch"):
        render(torch.zeros(1, 1, 8, 8), psfs.float(), fields, patch=5)


def test_a_crop_at_its_offset_renders_as_that_part_of_the_frame():
    # A crop rendered with offset_px (its centre's position from the axis) and the frame's full
    # field equals the same region of the whole frame's render, away from the crop's border
    # (light from outside a crop is not modelled); a crop rendered at offset 0 does not.
    torch.manual_seed(0)
    psfs, fields = comatic_stack()
    vig = torch.linspace(1.0, 0.6, len(fields), dtype=torch.float64)[:, None].repeat(1, 3)
    h, w = 48, 64
    full = 0.5 * math.hypot(h - 1, w - 1)
    frame = torch.rand(1, 3, h, w, dtype=torch.float64)
    whole = render_exact(frame, psfs, fields, vig)
    y0, x0, ch, cw = 4, 30, 24, 30
    crop = frame[..., y0 : y0 + ch, x0 : x0 + cw]
    offset = (y0 + (ch - 1) / 2 - (h - 1) / 2, x0 + (cw - 1) / 2 - (w - 1) / 2)
    m = psfs.shape[-1] // 2
    want = whole[..., y0 + m : y0 + ch - m, x0 + m : x0 + cw - m]
    got = render_exact(crop, psfs, fields, vig, full_field_px=full, offset_px=offset)[..., m:-m, m:-m]
    assert torch.allclose(got, want, atol=1e-12)
    wrong = render_exact(crop, psfs, fields, vig, full_field_px=full)[..., m:-m, m:-m]
    assert (wrong - want).abs().max() > 1e-3
    # overlap-add: the same up to its patch blending (8 px patches)
    ola = render(crop, psfs, fields, vig, patch=8, full_field_px=full, offset_px=offset)[..., m:-m, m:-m]
    assert ((ola - want).abs().sum() / want.abs().sum()).item() < 0.01
    with pytest.raises(ValueError, match="full_field_px"):
        render(crop, psfs, fields, offset_px=offset)


def test_gradients_repeat_bit_for_bit_with_several_threads():
    # a design run must follow the same path when run again: the field interpolation's
    # backward once accumulated by advanced indexing, in parallel and in no fixed order
    psfs, fields = comatic_stack(k=6, s=21)
    psfs = psfs.float()
    vig = torch.linspace(1.0, 0.7, 6)[:, None].repeat(1, 3)
    image = torch.rand(2, 3, 96, 96, generator=torch.Generator().manual_seed(0))
    threads = torch.get_num_threads()
    torch.set_num_threads(4)
    try:
        grads = []
        for _ in range(4):
            p = psfs.clone().requires_grad_(True)
            v = vig.clone().requires_grad_(True)
            render(image, p, fields, v, patch=16, full_field_px=60.0).square().sum().backward()
            grads.append(torch.cat([p.grad.reshape(-1), v.grad.reshape(-1)]))
    finally:
        torch.set_num_threads(threads)
    for g in grads[1:]:
        assert torch.equal(g, grads[0])


def test_bilinear_rotation_spreads_a_delta_so_a_perfect_lens_bypasses_the_renderer():
    # Resampling a PSF to a patch's azimuth blurs it by the bilinear kernel: a delta keeps all
    # of its energy in the centre pixel only at multiples of 90 degrees (at 45 degrees 0.745,
    # the rest on its neighbours). A perfect lens (camera.PerfectOptics) must not pay that.
    from optix_e2e.camera import Camera, PerfectOptics, SensorStage
    from optix_e2e.isp.classical import ClassicalISP

    d = torch.zeros(1, 1, 9, 9, dtype=torch.float64)
    d[..., 4, 4] = 1.0
    assert float(rotate_psfs(d, torch.tensor([math.pi / 2], dtype=torch.float64))[0, 0, 4, 4]) == pytest.approx(1.0)
    assert float(rotate_psfs(d, torch.tensor([math.pi / 4], dtype=torch.float64))[0, 0, 4, 4]) == pytest.approx(
        0.745, abs=2e-3
    )

    optics = PerfectOptics(9, full_field_px=500.0)
    scene = torch.rand(2, 3, 24, 24)
    assert optics.psf_size == 9 and optics.block() is None
    assert torch.equal(optics(scene, (100.0, -50.0)), scene)
    preset = "imx249"
    cam = Camera(optics, SensorStage(preset), ClassicalISP(preset))
    out, raw = cam(scene, (0.0, 0.0), torch.Generator().manual_seed(0))
    assert raw.shape == (2, 1, 16, 16) and out.shape == (2, 3, 16, 16)  # the margin (4 px) cut
