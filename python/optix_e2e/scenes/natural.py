"""Training scenes with the statistics of real photographs (the ISP's and the tasks' training
stream; the held-out set never draws from these):

* ``natural_dead_leaves``: dead leaves (occlusion, r**-3 scale invariance) whose colours are
  drawn from the training photographs' pixels (the colour distribution of real photos), each
  leaf shaded by a linear gradient and the whole lit by a smooth random illumination field.
* ``text_scene``: lines of text in random sizes (6-48 px), fonts and colours (matplotlib's
  DejaVu fonts, rendered by Pillow): fine, high-contrast strokes.
* ``gradient_scene``: smooth colour ramps (linear and radial) with a few soft-edged shapes.
* ``texture_scene``: the greyscale texture and document photos scikit-image ships (brick,
  grass, gravel, text, page, coins, camera, moon), tinted between two random colours.
* ``photo_crop``: a random crop of a training photograph at a random scale, flip and rotation.
* ``corpus_photo``: a crop at native scale of a photograph of a prepared corpus
  (scenes/corpus.py), with flips and 90-degree turns; drawn only when a corpus is given, and
  then the mix is :data:`PHOTO_MIX` (photographs the majority, the procedural kinds a minority).

Which photographs train and which are held out (docs/isp.md): the 9 colour photos of
scikit-image (``photos.bundled_photos``) are the held-out set and are never used here; the
training photos are scikit-learn's two (china, flower), matplotlib's colour samples
(grace_hopper, Minduka_Present_Blue_Pack) and the greyscale ones above.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..color import linear_to_srgb, srgb_to_linear
from ..errors import InputError
from .photos import to_image_tensor
from .procedural import _hw, _rng, dead_leaves

__all__ = [
    "natural_dead_leaves",
    "text_scene",
    "gradient_scene",
    "texture_scene",
    "photo_crop",
    "training_photos",
    "natural_scene",
]


def _package_dir(module: str) -> Path | None:
    try:
        mod = __import__(module, fromlist=["__file__"])
    except ImportError:
        return None
    return Path(mod.__file__).parent


# package -> (sub-folder, files): photographs shipped inside installed packages
_COLOUR_FILES = {
    "sklearn": ("datasets/images", ("china.jpg", "flower.jpg")),
    "matplotlib": ("mpl-data/sample_data", ("grace_hopper.jpg", "Minduka_Present_Blue_Pack.png")),
}
_GREY_FILES = ("brick.png", "grass.png", "gravel.png", "text.png", "page.png", "coins.png", "camera.png", "moon.png")


def _files(package: str, sub: str, names) -> list[Path]:
    root = _package_dir(package)
    return [] if root is None else [root / sub / n for n in names if (root / sub / n).is_file()]


@functools.lru_cache(maxsize=1)
def training_photos() -> tuple[torch.Tensor, ...]:
    """The colour training photographs found in the installed packages, sRGB [3, H, W] each."""
    import imageio.v3 as iio

    paths = [p for pkg, (sub, names) in _COLOUR_FILES.items() for p in _files(pkg, sub, names)]
    return tuple(to_image_tensor(iio.imread(p)) for p in paths)


@functools.lru_cache(maxsize=1)
def _textures() -> tuple[torch.Tensor, ...]:
    import imageio.v3 as iio

    return tuple(to_image_tensor(iio.imread(p))[:1] for p in _files("skimage", "data", _GREY_FILES))


@functools.lru_cache(maxsize=1)
def _palette() -> torch.Tensor:
    """Pixel colours of the training photos (each reduced to 48 x 48), [N, 3] sRGB."""
    pix = [F.interpolate(p[None], size=(48, 48), mode="area")[0].reshape(3, -1).T for p in training_photos()]
    return torch.cat(pix) if pix else torch.rand(4096, 3, generator=torch.Generator().manual_seed(0))


def _smooth_field(h: int, w: int, rng, lo: float, hi: float, cells: int = 4) -> torch.Tensor:
    """[1, H, W] a smooth random field in [lo, hi] (bicubic from a cells x cells grid)."""
    g = torch.from_numpy(rng.random((1, 1, cells, cells), dtype=np.float32))
    f = F.interpolate(g, size=(h, w), mode="bicubic", align_corners=True)[0].clamp(0, 1)
    return lo + (hi - lo) * f


def natural_dead_leaves(size, seed=None) -> torch.Tensor:
    rng = _rng(seed)
    h, w = _hw(size)
    img = dead_leaves((h, w), rng, alpha=float(rng.uniform(2.6, 3.4)), colors=_palette().numpy())
    lin = srgb_to_linear(img)
    # shading: a linear ramp over the image and a smooth illumination field
    ang = rng.uniform(0, 2 * np.pi)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    ramp = 1 + float(rng.uniform(0, 0.4)) * (np.cos(ang) * xx + np.sin(ang) * yy)
    lin = lin * ramp.clamp(min=0.2) * _smooth_field(h, w, rng, float(rng.uniform(0.4, 0.9)), 1.0)
    return linear_to_srgb(lin.clamp(0, 1))


def text_scene(size, seed=None) -> torch.Tensor:
    from matplotlib import font_manager
    from PIL import Image, ImageDraw, ImageFont

    rng = _rng(seed)
    h, w = _hw(size)
    fonts = sorted(Path(font_manager.__file__).parent.joinpath("mpl-data/fonts/ttf").glob("DejaVu*.ttf"))
    bg = tuple(int(v) for v in rng.integers(0, 256, 3))
    im = Image.new("RGB", (w, h), bg)
    draw = ImageDraw.Draw(im)
    alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 .,:-+/()"
    y = int(rng.integers(-8, 8))
    while y < h:
        px = int(np.exp(rng.uniform(np.log(6), np.log(48))))
        font = ImageFont.truetype(str(fonts[int(rng.integers(len(fonts)))]), px) if fonts else ImageFont.load_default()
        fg = np.array(bg) + rng.choice([-1, 1]) * rng.integers(60, 256, 3)
        text = "".join(rng.choice(list(alphabet), int(rng.integers(5, 40))))
        draw.text(
            (int(rng.integers(-20, max(1, w // 3))), y),
            text,
            fill=tuple(int(v) for v in np.clip(fg, 0, 255)),
            font=font,
        )
        y += int(px * rng.uniform(1.0, 1.6))
    return torch.from_numpy(np.asarray(im, dtype=np.float32) / 255).permute(2, 0, 1).contiguous()


def gradient_scene(size, seed=None) -> torch.Tensor:
    rng = _rng(seed)
    h, w = _hw(size)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    c0, c1 = (torch.from_numpy(rng.random(3, dtype=np.float32))[:, None, None] for _ in range(2))
    if rng.random() < 0.5:
        ang = rng.uniform(0, 2 * np.pi)
        t = (np.cos(ang) * xx + np.sin(ang) * yy + 1.5) / 3
    else:
        cy, cx = rng.uniform(-1, 1, 2)
        t = ((yy - cy) ** 2 + (xx - cx) ** 2).sqrt() / float(rng.uniform(0.5, 2.5))
    img = c0 + (c1 - c0) * t.clamp(0, 1)
    for _ in range(int(rng.integers(0, 5))):  # soft-edged discs and bars
        col = torch.from_numpy(rng.random(3, dtype=np.float32))[:, None, None]
        cy, cx, r = rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.05, 0.5)
        soft = float(rng.uniform(0.005, 0.1))
        if rng.random() < 0.5:
            d = ((yy - cy) ** 2 + (xx - cx) ** 2).sqrt() - r
        else:
            d = (yy - cy).abs() - r / 3
        a = torch.sigmoid(-d / soft)
        img = img * (1 - a) + col * a
    return img.clamp(0, 1)


def _random_view(img: torch.Tensor, h: int, w: int, rng, min_scale: float) -> torch.Tensor:
    """A random crop of ``img`` at a random scale in [min_scale, 1] (never upsampled past 1:1
    unless the image is too small), random flips and 90-degree turns."""
    if rng.random() < 0.5:
        img = img.transpose(-1, -2)
    H, W = img.shape[-2:]
    s = float(np.exp(rng.uniform(np.log(min_scale), 0)))
    s = max(s, h / H, w / W)
    hh, ww = max(h, int(round(H * s))), max(w, int(round(W * s)))
    if (hh, ww) != (H, W):
        img = F.interpolate(
            img[None],
            size=(hh, ww),
            mode="area" if s < 1 else "bilinear",
            **({} if s < 1 else {"align_corners": False}),
        )[0]
    y, x = int(rng.integers(0, hh - h + 1)), int(rng.integers(0, ww - w + 1))
    out = img[:, y : y + h, x : x + w]
    if rng.random() < 0.5:
        out = out.flip(-1)
    if rng.random() < 0.5:
        out = out.flip(-2)
    return out.contiguous()


def texture_scene(size, seed=None) -> torch.Tensor:
    rng = _rng(seed)
    h, w = _hw(size)
    tex = _textures()
    if not tex:
        return natural_dead_leaves((h, w), rng)
    g = _random_view(tex[int(rng.integers(len(tex)))], h, w, rng, 0.3)
    pal = _palette()
    c0, c1 = (srgb_to_linear(pal[int(rng.integers(len(pal)))])[:, None, None] for _ in range(2))
    return linear_to_srgb(c0 + (c1 - c0) * srgb_to_linear(g))


def photo_crop(size, seed=None) -> torch.Tensor:
    rng = _rng(seed)
    h, w = _hw(size)
    photos = training_photos()
    if not photos:
        return natural_dead_leaves((h, w), rng)
    return _random_view(photos[int(rng.integers(len(photos)))], h, w, rng, 0.25)


# the training mix of every stage that learns from scenes (ISP pre-training and the tasks)
NATURAL_MIX = {
    "natural_dead_leaves": 0.4,
    "photo_crop": 0.2,
    "texture_scene": 0.15,
    "text_scene": 0.1,
    "gradient_scene": 0.05,
    "slanted_edge": 0.05,
    "color_chart": 0.05,
}


# the mix when a corpus of photographs is given: its crops the majority, the procedural kinds a
# minority kept for what photographs rarely hold (fine text, hard edges, saturated charts)
PHOTO_MIX = {
    "corpus_photo": 0.7,
    "natural_dead_leaves": 0.1,
    "text_scene": 0.08,
    "texture_scene": 0.04,
    "gradient_scene": 0.02,
    "slanted_edge": 0.03,
    "color_chart": 0.03,
}


def natural_scene(size, seed=None, mix: dict[str, float] | None = None, corpus=None) -> torch.Tensor:
    """One training scene drawn from ``mix`` (default :data:`NATURAL_MIX`, or :data:`PHOTO_MIX`
    with a ``corpus``: a scenes.corpus.PhotoCorpus)."""
    from . import procedural

    rng = _rng(seed)
    mix = mix or (NATURAL_MIX if corpus is None else PHOTO_MIX)
    kinds = list(mix)
    p = np.array([mix[k] for k in kinds], float)
    kind = kinds[rng.choice(len(kinds), p=p / p.sum())]
    if kind == "slanted_edge":
        angle = float(rng.uniform(2, 10) * rng.choice([-1, 1]) + 90 * rng.integers(0, 4))
        return procedural.slanted_edge(size, angle, float(rng.uniform(2, 10)), rng, light=float(rng.uniform(0.3, 0.9)))
    if kind == "color_chart":
        return procedural.color_chart(size, surround=float(rng.uniform(0.2, 0.8)))
    if kind == "corpus_photo":
        if corpus is None:
            raise InputError("scene kind corpus_photo needs a corpus of photographs")
        return corpus.view(*_hw(size), rng)
    fn = {
        "natural_dead_leaves": natural_dead_leaves,
        "photo_crop": photo_crop,
        "texture_scene": texture_scene,
        "text_scene": text_scene,
        "gradient_scene": gradient_scene,
    }.get(kind)
    if fn is None:
        raise InputError(f"unknown scene kind {kind!r}; use {', '.join(PHOTO_MIX)}, photo_crop")
    return fn(size, rng)
