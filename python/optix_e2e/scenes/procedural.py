"""Procedural scenes: dead-leaves charts, slanted edges, ColorChecker charts.

All return float32 sRGB tensors [3,H,W] in [0,1]; ``size`` is an int (square) or (h, w);
``seed`` is an int, None (fresh entropy) or a ``numpy.random.Generator`` (consumed).

Dead leaves (Matheron 1968; Lee, Mumford & Huang, "Occlusion models for natural images",
IJCV 2001): opaque discs with radius density ~ r**-alpha fall on top of each other.  With
alpha = 3 the model is scale invariant and reproduces the ~1/f**2 power spectrum and the
occlusion edges of natural images, which is why it is the texture chart of camera
texture-acutance measurement (Cao, Guichard & Hornung 2010; IEEE 1858 CPIQ; ISO 19567-2).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F

from ..color import colorchecker_srgb, linear_to_srgb, srgb_to_linear
from ..errors import InputError

__all__ = ["dead_leaves", "slanted_edge", "color_chart", "chart_patch_boxes", "mixed_scene", "random_crops"]


def _hw(size) -> tuple[int, int]:
    h, w = (size, size) if isinstance(size, (int, np.integer)) else (int(size[0]), int(size[1]))
    if h < 1 or w < 1:
        raise InputError(f"size must be positive, got {size}")
    return int(h), int(w)


def _rng(seed) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


# ----------------------------------------------------------------------------- dead leaves


def _power_law(rng: np.random.Generator, n: int, lo: float, hi: float, exponent: float) -> np.ndarray:
    """``n`` samples with density ~ r**exponent on [lo, hi] (inverse CDF)."""
    u = rng.random(n)
    e = exponent + 1.0
    if abs(e) < 1e-9:
        return lo * (hi / lo) ** u
    return (lo**e + u * (hi**e - lo**e)) ** (1.0 / e)


_NONE = np.iinfo(np.int64).max  # label of a pixel no disc covers (yet)
_CHUNK = 4_000_000  # elements per vectorised step


def _disk_radii(rng, n, lo, hi, alpha, h, w) -> np.ndarray:
    """Radii of the discs that can touch an h x w image, for radius density r**-alpha per area.

    A disc of radius r touches the image only if its centre lies in the image grown by r, so
    the radii of those discs have density r**-alpha (h + 2r)(w + 2r): a mixture of three
    power laws, sampled exactly.  (Sampling r**-alpha and then a centre in the grown box
    would under-weight large discs.)
    """
    coef = np.array([h * w, 2.0 * (h + w), 4.0])
    powers = np.array([-alpha, 1.0 - alpha, 2.0 - alpha])
    mass = (
        np.array([np.log(hi / lo) if abs(p + 1) < 1e-9 else (hi ** (p + 1) - lo ** (p + 1)) / (p + 1) for p in powers])
        * coef
    )
    which = rng.choice(3, size=n, p=mass / mass.sum())
    samples = np.stack([_power_law(rng, n, lo, hi, p) for p in powers])
    return samples[which, np.arange(n)]


def _stamp(label: np.ndarray, h: int, w: int, cx, cy, r, first: int) -> None:
    """label[pixel] = min(label, index of the first disc covering the pixel centre), vectorised.

    Discs are grouped by radius octave; each group is tested either on a stencil just
    large enough for its discs or, when fewer pixels are still uncovered than the stencil
    holds, directly against those pixels (covered pixels never change: later discs lie
    beneath).  With r**-3 radii every octave then costs about the same.  numpy, not torch:
    hundreds of small ops, which torch's thread pool slows down badly on a busy machine.
    """
    ids = np.arange(first, first + len(r))
    todo = np.flatnonzero(label == _NONE)
    ty, tx = todo // w + 0.5, todo % w + 0.5
    octave = np.ceil(np.log2(np.maximum(r, 1.0))).astype(np.int64)
    for k in np.unique(octave).tolist():
        sel = np.flatnonzero(octave == k)
        off = np.arange(-(2**k) - 1, 2**k + 1)
        direct = len(todo) < len(off) ** 2
        step = max(1, _CHUNK // (len(todo) if direct else len(off) ** 2))
        for s in range(0, len(sel), step):
            j = sel[s : s + step]
            if direct:  # [discs, uncovered pixels]
                hit = (tx - cx[j, None]) ** 2 + (ty - cy[j, None]) ** 2 <= r[j, None] ** 2
                label[todo] = np.minimum(label[todo], np.where(hit, ids[j, None], _NONE).min(0))
                continue
            px = np.floor(cx[j]).astype(np.int64)[:, None, None] + off[None, None, :]
            py = np.floor(cy[j]).astype(np.int64)[:, None, None] + off[None, :, None]
            d2 = (px + 0.5 - cx[j, None, None]) ** 2 + (py + 0.5 - cy[j, None, None]) ** 2
            hit = (d2 <= r[j, None, None] ** 2) & (px >= 0) & (px < w) & (py >= 0) & (py < h)
            flat = np.broadcast_to(py * w + px, hit.shape)[hit]
            np.minimum.at(label, flat, np.broadcast_to(ids[j, None, None], hit.shape)[hit])


# everyday scenes only: retina, ihc (microscopy) and hubble_deep_field (mostly black) would
# skew the palette towards red and black.
_PALETTE_PHOTOS = ("astronaut", "chelsea", "coffee", "rocket", "motorcycle_left")


@functools.lru_cache(maxsize=1)
def _photo_palette() -> torch.Tensor:
    """Pixel colours of the everyday bundled photos (each reduced to 32x32), [N,3] sRGB."""
    from .photos import bundled_photos, load_photo

    pix = [load_photo(n, 32).reshape(3, -1).T for n in _PALETTE_PHOTOS if n in bundled_photos()]
    return torch.cat(pix) if pix else torch.empty(0, 3)


def _colors(rng, n: int, colors) -> torch.Tensor:
    if isinstance(colors, str):
        if colors == "photos":
            pool = _photo_palette()
            if len(pool):
                return pool[torch.from_numpy(rng.integers(0, len(pool), n))]
            colors = "uniform"  # no photos installed: fall back
        if colors == "uniform":
            return torch.from_numpy(rng.random((n, 3), dtype=np.float32))
        if colors == "grey":
            return torch.from_numpy(rng.random((n, 1), dtype=np.float32)).expand(n, 3)
        raise InputError(f"unknown colors {colors!r}; use 'photos', 'uniform', 'grey' or an [K,3] array")
    pool = torch.as_tensor(np.asarray(colors), dtype=torch.float32)
    if pool.ndim != 2 or pool.shape[1] != 3:
        raise InputError(f"a colour palette must have shape [K, 3], got {tuple(pool.shape)}")
    return pool[torch.from_numpy(rng.integers(0, len(pool), n))]


def dead_leaves(
    size,
    seed=None,
    *,
    r_min: float = 1.0,
    r_max: float | None = None,
    alpha: float = 3.0,
    colors="photos",
    supersample: int = 2,
    max_disks: int = 2_000_000,
) -> torch.Tensor:
    """A dead-leaves chart: occluding discs, radius density ~ r**-alpha on [r_min, r_max].

    Radii are in output pixels; ``r_max`` defaults to half the larger image side.  The
    first disc drawn lies on top and drawing stops once every pixel is covered, which
    gives an exact sample of the stationary model (Kendall & Thoennes 1999) with no
    boundary effects: discs centred outside the frame are included.  ``colors``:

    * ``"photos"`` (default): each disc takes the colour of a random pixel of the bundled
      everyday photos (astronaut, chelsea, coffee, rocket, motorcycle), so the colour
      distribution is that of natural images.
      Only colour statistics are used, not the photos' structure.  Falls back to
      ``"uniform"`` if no photo is installed.
    * ``"uniform"``: uniform in the sRGB cube;  ``"grey"``: uniform grey levels (the
      classic texture-acutance chart);  or an array [K,3] of sRGB colours to draw from.

    Edges are anti-aliased by rendering at ``supersample`` x the resolution and averaging
    in linear light.  Discs are stamped in vectorised octave groups: ~15 ms for 128x128,
    ~0.3 s for 512x512 (one core); the first ``"photos"`` call also builds the palette
    (~0.3 s).  Should ``max_disks`` discs not cover the frame, the rest gets one colour.
    """
    h, w = _hw(size)
    rng = _rng(seed)
    s = int(supersample)
    if s < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")
    H, W = h * s, w * s
    lo, hi = r_min * s, (r_max if r_max is not None else max(h, w) / 2) * s
    if not 0 < lo < hi:
        raise InputError(f"need 0 < r_min < r_max, got r_min={r_min}, r_max={r_max}")
    label = np.full(H * W, _NONE, dtype=np.int64)
    n, batch = 0, 1024
    while n < max_disks:
        r = _disk_radii(rng, batch, lo, hi, alpha, H, W)
        cx, cy = rng.uniform(-r, W + r), rng.uniform(-r, H + r)
        _stamp(label, H, W, cx, cy, r, n)
        n += batch
        if int(label.max()) < n:  # every pixel covered
            break
        batch *= 2
    col = srgb_to_linear(_colors(rng, n + 1, colors))  # index n: fill for any uncovered pixel
    img = col[torch.from_numpy(np.minimum(label, n))].T.reshape(3, H, W)
    if s > 1:
        img = F.avg_pool2d(img[None], s)[0]
    return linear_to_srgb(img).clamp(0.0, 1.0).contiguous()


# --------------------------------------------------------------------------- slanted edge


def _box_cdf(t: torch.Tensor, a: float, b: float) -> torch.Tensor:
    """CDF of U(-a/2, a/2) + U(-b/2, b/2): the fraction of a unit pixel on one side of a line.

    For a line with unit normal (nx, ny) at signed distance t from the pixel centre, the
    covered fraction of the pixel is this CDF with a = |nx|, b = |ny| (exact area coverage).
    """
    a, b = max(a, 1e-6), max(b, 1e-6)
    t = t.clamp(-1.0, 1.0)
    p, m = (a + b) / 2, (a - b) / 2

    def q(x):
        return x.clamp(min=0) ** 2 / 2

    return ((q(t + p) - q(t + m) - q(t - m) + q(t - p)) / (a * b)).clamp(0.0, 1.0)


def slanted_edge(size, angle_deg: float = 5.0, contrast: float = 4.0, seed=None, *, light: float = 0.6) -> torch.Tensor:
    """An ISO 12233 style slanted edge: dark left, light right, through the image centre.

    The edge is the line x = xc + tan(angle) * (y - yc) (pixel coordinates, y down), so
    ``angle_deg`` is the tilt from vertical; 90 gives a horizontal edge (dark below).
    ``contrast`` is the light/dark ratio in linear light (ISO 12233:2014 uses 4:1) with
    the light side at ``light`` (linear).  Each pixel gets the exact area fraction of each
    side, mixed in linear light, then sRGB-encoded.  ``seed`` (if not None) shifts the edge
    by a random sub-pixel offset in [-0.5, 0.5) px along x.
    """
    h, w = _hw(size)
    if contrast < 1:
        raise InputError(f"contrast must be >= 1, got {contrast}")
    theta = math.radians(angle_deg)
    shift = 0.0 if seed is None else float(_rng(seed).uniform(-0.5, 0.5))
    y = torch.arange(h, dtype=torch.float64)[:, None] + 0.5 - h / 2
    x = torch.arange(w, dtype=torch.float64)[None, :] + 0.5 - w / 2 - shift
    dist = x * math.cos(theta) - y * math.sin(theta)  # signed distance, > 0 on the light side
    frac = _box_cdf(dist, abs(math.cos(theta)), abs(math.sin(theta)))
    lin = light / contrast + (light - light / contrast) * frac
    return linear_to_srgb(lin.float()).clamp(0.0, 1.0).expand(3, h, w).contiguous()


# ---------------------------------------------------------------------------- colour chart


def chart_patch_boxes(size, gap: float = 0.25) -> list[tuple[int, int, int, int]]:
    """Pixel boxes (y0, y1, x0, x1) of the 24 patches of :func:`color_chart`, in
    :data:`~optix_e2e.color.COLORCHECKER_NAMES` order (row by row).  ``gap`` is the gap
    between patches (and to the chart's edge) as a fraction of the patch side."""
    h, w = _hw(size)
    p = min(w / (6 + 7 * gap), h / (4 + 5 * gap))
    g = gap * p
    oy, ox = (h - (4 * p + 5 * g)) / 2, (w - (6 * p + 7 * g)) / 2
    boxes = []
    for i in range(24):
        row, col = divmod(i, 6)
        y0, x0 = oy + g + row * (p + g), ox + g + col * (p + g)
        boxes.append((round(y0), round(y0 + p), round(x0), round(x0 + p)))
    if any(y1 <= y0 or x1 <= x0 for y0, y1, x0, x1 in boxes):
        raise InputError(f"size {size} is too small for a 4x6 colour chart")
    return boxes


def color_chart(size, seed=None, *, surround: float = 0.5, gap: float = 0.25, jitter: float = 0.0) -> torch.Tensor:
    """The 24-patch ColorChecker (BabelColor averages, sRGB) as a 4x6 grid, centred on a
    uniform grey surround (sRGB value ``surround``).  Patch positions: :func:`chart_patch_boxes`.
    With ``jitter`` = 0 (the default) the chart is the standard one and ``seed`` is unused;
    with ``jitter`` > 0 the ``seed`` shuffles the patches over the grid and scales each
    patch's linear RGB by its own factors in [1 - jitter, 1 + jitter]: a chart no other seed
    (and not the standard chart) gives, e.g. for held-out scenes."""
    h, w = _hw(size)
    img = torch.full((3, h, w), float(surround))
    colours = colorchecker_srgb()
    if jitter:
        rng = _rng(seed)
        colours = colours[torch.from_numpy(rng.permutation(len(colours)))]
        scale = torch.from_numpy(rng.uniform(1 - jitter, 1 + jitter, colours.shape).astype(np.float32))
        colours = linear_to_srgb((srgb_to_linear(colours) * scale).clamp(0, 1))
    for (y0, y1, x0, x1), rgb in zip(chart_patch_boxes((h, w), gap), colours):
        img[:, y0:y1, x0:x1] = rgb[:, None, None]
    return img


# ------------------------------------------------------------------------------- mixtures


def mixed_scene(size, seed=None, *, weights: dict[str, float] | None = None) -> torch.Tensor:
    """A random procedural scene: by default dead leaves (70%, random alpha in [2.5, 3.5] and
    palette), a slanted edge (15%, random angle/orientation/contrast) or a colour chart (15%:
    shuffled and jittered by the seed, never the standard chart that training scenes use).
    The bundled photos are never used as structure, so they stay free for evaluation."""
    rng = _rng(seed)
    weights = weights or {"dead_leaves": 0.7, "slanted_edge": 0.15, "color_chart": 0.15}
    kinds = list(weights)
    p = np.array([weights[k] for k in kinds], dtype=float)
    kind = kinds[rng.choice(len(kinds), p=p / p.sum())]
    if kind == "dead_leaves":
        return dead_leaves(
            size,
            rng,
            alpha=float(rng.uniform(2.5, 3.5)),
            colors=str(rng.choice(["photos", "photos", "uniform", "grey"])),
        )
    if kind == "slanted_edge":
        angle = float(rng.uniform(2, 10) * rng.choice([-1, 1]) + 90 * rng.integers(0, 4))
        return slanted_edge(size, angle, float(rng.uniform(2, 10)), rng, light=float(rng.uniform(0.3, 0.9)))
    if kind == "color_chart":
        return color_chart(size, rng, surround=float(rng.uniform(0.2, 0.8)), jitter=0.2)
    raise InputError(f"unknown scene kind {kind!r}; use dead_leaves, slanted_edge, color_chart")


def random_crops(img: torch.Tensor, size, n: int, seed=None) -> torch.Tensor:
    """``n`` random crops of ``size`` from ``img`` [C,H,W], stacked as [n,C,h,w]."""
    h, w = _hw(size)
    _, H, W = img.shape
    if h > H or w > W:
        raise InputError(f"crop {h}x{w} does not fit in a {H}x{W} image")
    rng = _rng(seed)
    ys, xs = rng.integers(0, H - h + 1, n), rng.integers(0, W - w + 1, n)
    return torch.stack([img[:, y : y + h, x : x + w] for y, x in zip(ys.tolist(), xs.tolist())])
