"""PNG figures of PSFs (matplotlib, Agg canvas: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from .io import save_figure

LOG_FLOOR = 1e-4  # log plots show four decades below the peak


def _extent(shape: tuple[int, int], pixel_um: float) -> list[float]:
    """Axes in um relative to the chief ray (pixel size//2 is the chief-ray pixel)."""
    h, w = shape
    x0 = (-(w // 2) - 0.5) * pixel_um
    y0 = (-(h // 2) - 0.5) * pixel_um
    return [x0, x0 + w * pixel_um, y0, y0 + h * pixel_um]


def _show(ax, image, pixel_um, log, cmap="inferno"):
    peak = float(np.max(image)) if image.size else 0.0
    norm = LogNorm(vmin=max(peak, 1e-30) * LOG_FLOOR, vmax=max(peak, 1e-30)) if log else None
    data = np.clip(image, max(peak, 1e-30) * LOG_FLOOR, None) if log else image
    return ax.imshow(
        data, origin="lower", extent=_extent(image.shape, pixel_um), cmap=cmap, norm=norm, interpolation="nearest"
    )


def save_psf_png(path: str | Path, image: np.ndarray, pixel_um: float, title: str = "", log: bool = False):
    """One PSF with a colour bar, axes in um."""
    fig = Figure(figsize=(5, 4.2), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    im = _show(ax, image, pixel_um, log)
    fig.colorbar(im, ax=ax, label="fraction of pupil flux per pixel")
    ax.set_xlabel("x (um)")
    ax.set_ylabel("y (um)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def rgb_composite(channels: np.ndarray, log: bool = False) -> np.ndarray:
    """(3, H, W) channel PSFs (R, G, B) -> (H, W, 3) image in [0, 1], common scale."""
    peak = float(np.max(channels)) or 1.0
    x = np.clip(channels / peak, 0.0, 1.0)
    if log:
        x = np.clip(1.0 + np.log10(np.maximum(x, LOG_FLOOR)) / -np.log10(LOG_FLOOR), 0.0, 1.0)
    return np.moveaxis(x, 0, -1)


def save_psf_grid(
    path: str | Path,
    psfs: np.ndarray,
    fields_deg: Sequence[float],
    pixel_um: float,
    channel_labels: Sequence[str],
    title: str = "",
    log: bool = False,
    row_notes: Sequence[str] | None = None,
):
    """Grid of PSFs: one row per field, one column per channel plus an RGB composite.

    ``psfs`` is (F, C, H, W); the composite uses the first three channels as R, G, B;
    ``row_notes`` (one short string per field) is appended to the composite's title.
    """
    n_f, n_c = psfs.shape[:2]
    composite = n_c >= 3
    cols = n_c + (1 if composite else 0)
    fig = Figure(figsize=(2.6 * cols, 2.4 * n_f + 0.6), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_f, cols, squeeze=False)
    cmaps = ["Reds", "Greens", "Blues"] if n_c == 3 else ["inferno"] * n_c
    for i, f in enumerate(fields_deg):
        for c in range(n_c):
            ax = axes[i, c]
            _show(ax, psfs[i, c], pixel_um, log, cmap=cmaps[c] if not log else "inferno")
            ax.set_title(f"{f:g} deg, {channel_labels[c]}", fontsize=8)
        if composite:
            ax = axes[i, n_c]
            ax.imshow(
                rgb_composite(psfs[i, :3], log),
                origin="lower",
                extent=_extent(psfs.shape[2:], pixel_um),
                interpolation="nearest",
            )
            note = f" ({row_notes[i]})" if row_notes else ""
            ax.set_title(f"{f:g} deg, RGB{note}", fontsize=8)
        axes[i, 0].set_ylabel("y (um)", fontsize=7)
    # every panel has the same extent: ticks on the left column and the bottom row only (the
    # ticks of 50 panels were most of the drawing time)
    for (i, j), ax in np.ndenumerate(axes):
        if i < n_f - 1:
            ax.set_xticks([])
        if j > 0:
            ax.set_yticks([])
        ax.tick_params(labelsize=6)
    for ax in axes[-1]:
        ax.set_xlabel("x (um)", fontsize=7)
    scale = "log10, 4 decades" if log else "linear"
    # fixed margins in inches (tight_layout measured every label of every panel: seconds per grid)
    w, h = fig.get_size_inches()
    fig.suptitle(f"{title} ({scale}; centred on the chief ray)", fontsize=10, y=1 - 0.2 / h)
    fig.subplots_adjust(left=0.55 / w, right=1 - 0.15 / w, bottom=0.45 / h, top=1 - 0.75 / h, wspace=0.45, hspace=0.4)
    save_figure(fig, path)


# ----------------------------------------------------------------------------- lens figures
