"""Errors of an approximate PSF against a reference on the same pixel grid.

Every PSF here is a (size, size) array of the fraction of the entrance-pupil flux per
pixel, centred on the chief ray (the engine's convention), so energy errors count too."""

from __future__ import annotations

import numpy as np


def rel_l1(a: np.ndarray, ref: np.ndarray) -> float:
    """sum |a - ref| / sum |ref|."""
    return float(np.abs(a - ref).sum() / np.abs(ref).sum())


def rel_l2(a: np.ndarray, ref: np.ndarray) -> float:
    """||a - ref||_2 / ||ref||_2."""
    return float(np.linalg.norm(a - ref) / np.linalg.norm(ref))


def ee_radius(
    psf: np.ndarray, pixel_um: float, fraction: float = 0.8, centre: tuple[float, float] | None = None
) -> float:
    """Radius (um) of the circle around ``centre`` (pixels (row, col); default the PSF's
    centroid) holding ``fraction`` of the PSF's energy in the window: the encircled-energy
    curve over pixel-centre distances, interpolated linearly."""
    p = np.asarray(psf, float)
    total = p.sum()
    if not total > 0:
        return float("nan")
    r, c = np.indices(p.shape)
    if centre is None:
        centre = ((r * p).sum() / total, (c * p).sum() / total)
    d = np.hypot(r - centre[0], c - centre[1]).ravel()
    order = np.argsort(d, kind="stable")
    cum = np.cumsum(p.ravel()[order]) / total
    k = int(np.searchsorted(cum, fraction))
    if k == 0:
        return float(d[order[0]] * pixel_um)
    if k >= len(cum):
        return float(d[order[-1]] * pixel_um)
    d0, d1, c0, c1 = d[order[k - 1]], d[order[k]], cum[k - 1], cum[k]
    return float((d0 + (fraction - c0) / max(c1 - c0, 1e-300) * (d1 - d0)) * pixel_um)


def scene_chart(size: int = 192, seed: int = 0) -> np.ndarray:
    """A deterministic grey test scene (size x size, values in [0, 1]) with detail at every
    scale: a Siemens star in one quadrant, dead leaves (discs with a power-law size
    distribution, the natural-image statistic) elsewhere, and a slanted edge."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(float)
    img = np.full((size, size), 0.5)
    # dead leaves: discs drawn back to front, radii ~ r^-3 between 1 and size/6 pixels
    rmin, rmax = 1.0, size / 6
    for _ in range(12 * size):
        u = rng.random()
        r = (rmin**-2 + u * (rmax**-2 - rmin**-2)) ** -0.5
        cy, cx = rng.random(2) * size
        img[(y - cy) ** 2 + (x - cx) ** 2 <= r * r] = rng.random()
    # Siemens star (36 spokes) in the top-left quadrant
    h = size // 2
    cy = cx = h / 2
    ang = np.arctan2(y[:h, :h] - cy, x[:h, :h] - cx)
    rad = np.hypot(y[:h, :h] - cy, x[:h, :h] - cx)
    star = 0.5 + 0.5 * np.sign(np.sin(18 * ang))
    img[:h, :h] = np.where(rad < h / 2 - 1, star, img[:h, :h])
    # slanted edge (5 deg) across the bottom-right quadrant
    q = (x[h:, h:] - h) * np.cos(np.radians(5)) - (y[h:, h:] - h) * np.sin(np.radians(5))
    img[h:, h:] = np.where(q < h / 2, 0.15, 0.85)
    return img


def render(img: np.ndarray, psf: np.ndarray) -> np.ndarray:
    """``img`` blurred by ``psf`` (same pixel pitch; the PSF's centre pixel size // 2 is
    the origin), circular convolution by FFT over a grid padded to hold both."""
    n = img.shape[0] + psf.shape[0]
    f = np.fft.rfft2(img, (n, n)) * np.fft.rfft2(psf, (n, n))
    out = np.fft.irfft2(f, (n, n))
    c = psf.shape[0] // 2
    return out[c : c + img.shape[0], c : c + img.shape[1]]


def render_error(a: np.ndarray, ref: np.ndarray, img: np.ndarray) -> float:
    """Relative L2 error of the test image rendered through ``a`` against through ``ref``,
    over the image interior (a PSF half-width, at most a quarter of the image, from the
    border: circular convolution wraps there)."""
    ra, rr = render(img, a), render(img, ref)
    m = min(a.shape[0] // 2, img.shape[0] // 4)
    sl = (slice(m, img.shape[0] - m), slice(m, img.shape[1] - m))
    return rel_l2(ra[sl], rr[sl])
