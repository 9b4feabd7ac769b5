"""Colour transfer functions, bundled photos, procedural scenes and the image-folder loader."""

from __future__ import annotations

import math
import socket

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from optix_e2e import scenes
from optix_e2e.color import COLORCHECKER_NAMES, COLORCHECKER_SRGB8, colorchecker_srgb, linear_to_srgb, srgb_to_linear
from optix_e2e.scenes import (
    ImageFolder,
    bundled_photos,
    chart_patch_boxes,
    color_chart,
    dead_leaves,
    load_photo,
    mixed_scene,
    random_crops,
    slanted_edge,
)
from optix_e2e.scenes.procedural import _disk_radii, _power_law

pytestmark = pytest.mark.usefixtures("one_torch_thread")

# ---------------------------------------------------------------------------------- colour


def test_srgb_known_values():
    x = torch.tensor([0.0, 0.04045, 0.5, 1.0], dtype=torch.float64)
    lin = srgb_to_linear(x)
    assert lin.tolist() == pytest.approx([0.0, 0.04045 / 12.92, 0.21404114, 1.0], abs=1e-7)
    # 18% grey encodes to ~0.4614 (118/255), the knee maps back to the knee
    assert linear_to_srgb(torch.tensor([0.18, 0.0031308], dtype=torch.float64)).tolist() == pytest.approx(
        [0.46135612, 0.04045], abs=1e-5
    )


def test_srgb_round_trip_and_finite_gradients():
    x = torch.linspace(-0.2, 1.3, 301, dtype=torch.float64)
    assert torch.allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)
    assert torch.allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    for f in (srgb_to_linear, linear_to_srgb):
        v = torch.tensor([-0.1, 0.0, 1e-4, 0.02, 0.5, 1.0, 1.2], dtype=torch.float64, requires_grad=True)
        f(v).sum().backward()
        assert torch.isfinite(v.grad).all() and (v.grad > 0).all(), (f.__name__, v.grad)


def test_colorchecker_constants_match_babelcolor_luminance():
    assert len(COLORCHECKER_NAMES) == len(COLORCHECKER_SRGB8) == 24
    rgb = colorchecker_srgb()
    assert rgb.shape == (24, 3) and rgb.dtype == torch.float32
    # luminance factor Y of the BabelColor average (D50), patch by patch
    y_ref = torch.tensor(
        [
            0.1034,
            0.3525,
            0.1847,
            0.1335,
            0.2324,
            0.4174,
            0.3117,
            0.1140,
            0.1979,
            0.0644,
            0.4435,
            0.4358,
            0.0579,
            0.2307,
            0.1268,
            0.6081,
            0.2007,
            0.1903,
            0.9129,
            0.5885,
            0.3595,
            0.1912,
            0.0893,
            0.0320,
        ]
    )
    y = colorchecker_srgb(linear=True) @ torch.tensor([0.2126, 0.7152, 0.0722])
    assert torch.allclose(y[18:], y_ref[18:], rtol=0.02)  # neutrals
    assert torch.allclose(y, y_ref, rtol=0.10)  # chromatic patches: gamut clipping, adaptation
    assert (rgb[18:].max(1).values - rgb[18:].min(1).values < 0.025).all()  # neutrals are grey


# ---------------------------------------------------------------------------------- photos


@pytest.fixture
def no_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("network access attempted")

    monkeypatch.setattr(socket, "socket", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def test_bundled_photos_load_offline_and_are_colour(no_network):
    names = bundled_photos()
    assert {"astronaut", "chelsea", "coffee", "rocket"} <= set(names)
    for name in names:
        img = load_photo(name, size=48)
        assert img.shape == (3, 48, 48) and img.dtype == torch.float32
        assert 0.0 <= img.min() and img.max() <= 1.0
        chroma = (img - img.mean(0, keepdim=True)).abs().mean()
        assert chroma > 0.005, f"{name} looks greyscale"


def test_load_photo_sizes_and_errors():
    full = load_photo("astronaut")
    assert full.shape == (3, 512, 512)
    assert load_photo("coffee", size=(40, 100)).shape == (3, 40, 100)
    # a square crop of a 400x600 photo keeps its centre
    sq = load_photo("coffee", size=400)
    assert torch.equal(sq, load_photo("coffee")[:, :, 100:500])
    with pytest.raises(ValueError, match="unknown photo 'camera'.*astronaut"):
        load_photo("camera")


# ----------------------------------------------------------------------------- dead leaves


def test_dead_leaves_reproducible():
    a = dead_leaves(128, 7)
    assert a.shape == (3, 128, 128) and a.dtype == torch.float32
    assert 0.0 <= a.min() and a.max() <= 1.0
    assert torch.equal(a, dead_leaves(128, 7))
    assert torch.equal(a, dead_leaves(128, np.random.default_rng(7)))
    assert not torch.equal(a, dead_leaves(128, 8))
    assert dead_leaves((40, 70), 1).shape == (3, 40, 70)


def test_dead_leaves_palette_and_grey():
    palette = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 1.0], [0.2, 0.2, 0.2]])
    img = dead_leaves(64, 0, colors=palette, supersample=1).reshape(3, -1).T.double()
    dist = torch.cdist(img, torch.from_numpy(palette)).min(1).values
    assert dist.max() < 1e-5  # without anti-aliasing every pixel is one palette colour
    grey = dead_leaves(64, 0, colors="grey")
    assert torch.equal(grey[0], grey[1]) and torch.equal(grey[1], grey[2])
    with pytest.raises(ValueError, match="unknown colors"):
        dead_leaves(32, 0, colors="pastel")


def _log_slope(samples: np.ndarray, lo: float, hi: float) -> float:
    edges = np.geomspace(lo, hi, 12)
    counts, _ = np.histogram(samples, edges)
    density = counts / np.diff(edges)
    return float(np.polyfit(np.log(np.sqrt(edges[1:] * edges[:-1])), np.log(density), 1)[0])


def test_radius_sampler_follows_power_law():
    rng = np.random.default_rng(0)
    assert _log_slope(_power_law(rng, 200_000, 1.0, 100.0, -3.0), 1.0, 100.0) == pytest.approx(-3.0, abs=0.05)
    # discs that can touch the frame: r**-3 (h + 2r)(w + 2r); for r << frame it is r**-3 ...
    r = _disk_radii(rng, 200_000, 1.0, 1000.0, 3.0, 10_000, 10_000)
    assert _log_slope(r, 1.0, 20.0) == pytest.approx(-3.0, abs=0.05)
    # ... while for r >> frame the (2r)^2 term wins: r**-1
    r = _disk_radii(rng, 200_000, 1.0, 1000.0, 3.0, 1, 1)
    assert _log_slope(r, 50.0, 1000.0) == pytest.approx(-1.0, abs=0.1)


def _spectrum_slope(alpha: float, n: int = 256, seeds=range(3)) -> float:
    """Log-log slope of the radially averaged power spectrum between 1/32 and 1/4 cycles/px."""
    power = 0.0
    for s in seeds:
        img = dead_leaves(n, s, alpha=alpha, colors="grey")[0].double().numpy()
        power = power + np.abs(np.fft.fft2(img - img.mean())) ** 2
    f = np.fft.fftfreq(n)
    fr = np.hypot(*np.meshgrid(f, f, indexing="ij")).ravel()
    edges = np.geomspace(8 / n, 0.25, 10)
    idx = np.digitize(fr, edges)
    pm = [power.ravel()[idx == i].mean() for i in range(1, len(edges))]
    return float(np.polyfit(np.log(np.sqrt(edges[1:] * edges[:-1])), np.log(pm), 1)[0])


def test_dead_leaves_power_spectrum_is_one_over_f_squared():
    slope = _spectrum_slope(3.0)
    assert slope == pytest.approx(-2.0, abs=0.25)
    # more small leaves (larger alpha) -> more high-frequency power -> flatter spectrum
    assert _spectrum_slope(3.6, n=128, seeds=range(2)) > _spectrum_slope(2.4, n=128, seeds=range(2)) + 0.3


# ---------------------------------------------------------------------------- slanted edge


@pytest.mark.parametrize("angle", [5.0, 11.0, -3.0])
def test_slanted_edge_angle_and_levels(angle):
    h, w, contrast, light = 64, 96, 4.0, 0.6
    img = slanted_edge((h, w), angle, contrast, light=light)
    assert img.shape == (3, h, w) and torch.equal(img[0], img[2])
    lin = srgb_to_linear(img[0].double())
    dark = light / contrast
    assert lin[:, 0] == pytest.approx(dark, abs=1e-6) and lin[:, -1] == pytest.approx(light, abs=1e-6)
    # exact area coverage: the light area in a row is (w - x_edge(row centre))
    frac = (lin - dark) / (light - dark)
    x_edge = w - frac.sum(1).numpy()
    slope = np.polyfit(np.arange(h) + 0.5, x_edge, 1)[0]
    assert math.degrees(math.atan(slope)) == pytest.approx(angle, abs=0.01)
    assert x_edge.mean() == pytest.approx(w / 2, abs=1e-3)  # float32 output


def test_slanted_edge_horizontal_and_shift():
    img = slanted_edge(32, 90.0)
    assert torch.allclose(img[0], img[0][:, :1].expand(32, 32))  # rows are constant
    assert img[0, 0, 0] > img[0, -1, 0]  # light on top, dark below
    a, b = slanted_edge(32, 5, seed=1), slanted_edge(32, 5, seed=2)
    assert torch.equal(a, slanted_edge(32, 5, seed=1)) and not torch.equal(a, b)


# ---------------------------------------------------------------------------- colour chart


def test_color_chart_patches_match_constants():
    size = (120, 200)
    img = color_chart(size, surround=0.4)
    boxes = chart_patch_boxes(size)
    mask = torch.zeros(size, dtype=torch.bool)
    for (y0, y1, x0, x1), rgb in zip(boxes, colorchecker_srgb()):
        assert 0 <= y0 < y1 <= 120 and 0 <= x0 < x1 <= 200
        assert not mask[y0:y1, x0:x1].any()  # disjoint
        mask[y0:y1, x0:x1] = True
        assert torch.equal(img[:, y0:y1, x0:x1], rgb[:, None, None].expand(3, y1 - y0, x1 - x0))
    assert (img[:, ~mask] == 0.4).all()
    assert boxes[0][0] == boxes[5][0] and boxes[0][2] < boxes[1][2]  # row-major order
    assert torch.equal(color_chart(size, 3, surround=0.4), img)  # seed accepted, chart fixed
    with pytest.raises(ValueError, match="too small"):
        color_chart(5)


def test_mixed_scene_and_random_crops():
    scenes = [mixed_scene(48, s) for s in range(12)]
    assert all(s.shape == (3, 48, 48) and 0 <= s.min() and s.max() <= 1 for s in scenes)
    assert torch.equal(scenes[3], mixed_scene(48, 3))
    assert len({tuple(s.flatten()[:50].tolist()) for s in scenes}) == 12
    img = torch.arange(3 * 20 * 30, dtype=torch.float32).reshape(3, 20, 30)
    crops = random_crops(img, (8, 10), 5, seed=0)
    assert crops.shape == (5, 3, 8, 10)
    for c in crops:  # each crop is a contiguous window of img
        y, x = divmod(int(c[0, 0, 0]), 30)
        assert torch.equal(c, img[:, y : y + 8, x : x + 10])
    with pytest.raises(ValueError, match="does not fit"):
        random_crops(img, 25, 1)


# ---------------------------------------------------------------------------- image folder


def test_image_folder_formats(tmp_path):
    rng = np.random.default_rng(0)
    rgb8 = rng.integers(0, 256, (10, 12, 3), dtype=np.uint8)
    grey16 = rng.integers(0, 65536, (10, 12), dtype=np.uint16)
    rgb16 = rng.integers(0, 65536, (10, 12, 3), dtype=np.uint16)
    grey8 = rng.integers(0, 256, (10, 12), dtype=np.uint8)
    rgba8 = rng.integers(0, 256, (10, 12, 4), dtype=np.uint8)
    (tmp_path / "sub").mkdir()
    iio.imwrite(tmp_path / "a_rgb8.png", rgb8)
    iio.imwrite(tmp_path / "b_grey16.png", grey16)
    iio.imwrite(tmp_path / "c_rgb16.tif", rgb16)
    iio.imwrite(tmp_path / "sub" / "d_grey8.PNG", grey8)
    iio.imwrite(tmp_path / "e_rgba8.png", rgba8)
    (tmp_path / "notes.txt").write_text("not an image")

    ds = ImageFolder(tmp_path)
    assert [p.name for p in ds.paths] == ["a_rgb8.png", "b_grey16.png", "c_rgb16.tif", "e_rgba8.png", "d_grey8.PNG"]
    expected = [
        rgb8 / 255.0,
        np.repeat(grey16[..., None] / 65535.0, 3, 2),
        rgb16 / 65535.0,
        rgba8[..., :3] / 255.0,
        np.repeat(grey8[..., None] / 255.0, 3, 2),
    ]
    for i, want in enumerate(expected):
        got = ds[i]
        assert got.shape == (3, 10, 12) and got.dtype == torch.float32
        np.testing.assert_allclose(got.permute(1, 2, 0).numpy(), want, atol=1e-6, err_msg=str(ds.paths[i]))
    assert len(ImageFolder(tmp_path, recursive=False)) == 4
    batch = torch.stack([ImageFolder(tmp_path, size=8)[i] for i in range(5)])
    assert batch.shape == (5, 3, 8, 8)


def test_image_folder_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        ImageFolder(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.md").write_text("x")
    with pytest.raises(ValueError, match="no images.*empty"):
        ImageFolder(tmp_path / "empty")
    bad = tmp_path / "bad"
    bad.mkdir()
    iio.imwrite(bad / "good.png", np.zeros((4, 4, 3), np.uint8))
    (bad / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    ds = ImageFolder(bad)
    assert ds[1].shape == (3, 4, 4)
    with pytest.raises(ValueError, match=r"cannot read image .*broken\.png"):
        ds[0]


# --- the natural training mix and the held-out split -----------------------------------------


def test_natural_training_scenes_are_images_and_repeat_with_their_seed():
    from optix_e2e.scenes import natural

    for kind in natural.NATURAL_MIX:
        a = natural.natural_scene((40, 56), np.random.default_rng(3), mix={kind: 1.0})
        b = natural.natural_scene((40, 56), np.random.default_rng(3), mix={kind: 1.0})
        assert a.shape == (3, 40, 56) and a.dtype == torch.float32, kind
        assert float(a.min()) >= 0 and float(a.max()) <= 1 and torch.equal(a, b), kind
        assert float(a.std()) > 0.01 or kind == "color_chart", kind  # not flat
    # the photographs the packages ship: four colour training photos, none of the held-out ones
    assert len(natural.training_photos()) == 4
    held = {tuple(scenes.load_photo(n, 32).flatten()[:50].tolist()) for n in scenes.bundled_photos()}
    assert not held & {tuple(scenes.fit_size(p, 32).flatten()[:50].tolist()) for p in natural.training_photos()}


def test_held_out_charts_are_not_the_training_chart():
    standard = scenes.color_chart(96)
    a, b = scenes.color_chart(96, 1, jitter=0.2), scenes.color_chart(96, 2, jitter=0.2)
    assert not torch.allclose(a, standard, atol=0.02) and not torch.allclose(a, b, atol=0.02)
    assert torch.equal(scenes.color_chart(96, 7), standard)  # no jitter: the standard chart, whatever the seed
    # a held-out procedural chart (mixed_scene) has no patch of the standard chart's colours
    ref = colorchecker_srgb()
    boxes = chart_patch_boxes(96)
    for seed in range(3):
        img = scenes.mixed_scene(96, seed, weights={"color_chart": 1.0})
        patches = torch.stack([img[:, (y0 + y1) // 2, (x0 + x1) // 2] for y0, y1, x0, x1 in boxes])
        nearest = torch.cdist(patches, ref).min(1).values
        assert (nearest > 2 / 255).sum() >= 20, nearest
