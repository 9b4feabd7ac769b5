"""PNG figures of a lens (matplotlib, Agg canvas): its layout with ray fans, spot diagrams per
field and MTF curves, as `optix lens report` and `optix lens plot` draw them."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..io import save_figure


def wavelength_rgb(nm: float) -> tuple[float, float, float]:
    """Approximate display colour of a wavelength (380-780 nm; grey outside)."""
    if nm < 380 or nm > 780:
        return (0.5, 0.5, 0.5)
    bands = [
        (380, 440, lambda t: (-(t - 440) / 60, 0.0, 1.0)),
        (440, 490, lambda t: (0.0, (t - 440) / 50, 1.0)),
        (490, 510, lambda t: (0.0, 1.0, -(t - 510) / 20)),
        (510, 580, lambda t: ((t - 510) / 70, 1.0, 0.0)),
        (580, 645, lambda t: (1.0, -(t - 645) / 65, 0.0)),
        (645, 781, lambda t: (1.0, 0.0, 0.0)),
    ]
    rgb = next(f(nm) for lo, hi, f in bands if lo <= nm < hi)
    return tuple(0.85 * c for c in rgb)  # a little darker: readable on white


def _field_colours(n: int):
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def _element_outline(front: dict, back: dict, sag, n: int = 81) -> np.ndarray:
    """Closed (z, y) outline of the glass between two surfaces: both profiles over their
    own semi-diameters, the smaller one carried out flat to the larger, edges joined."""
    h1, h2 = front["semi_diameter"], back["semi_diameter"]
    rim = max(h1, h2)
    r1, r2 = np.linspace(h1, -h1, n), np.linspace(-h2, h2, n)
    z1 = front["z"] + sag(front["surface"], r1)
    z2 = back["z"] + sag(back["surface"], r2)
    pts = [(z1[0], rim), *zip(z1, r1), (z1[-1], -rim), (z2[0], -rim), *zip(z2, r2), (z2[-1], rim)]
    return np.array(pts + [pts[0]])


def save_layout_png(
    path: str | Path,
    lens,
    fields: Sequence[float] | None = None,
    rays: int = 9,
    aiming: str = "paraxial",
    wavelength_nm: float | None = None,
) -> dict:
    """Meridional cross-section: surfaces as their real profiles, elements as closed
    shapes, stop and image plane marked, ray fans per field from a start plane before
    surface 1 to the image (or to where they are clipped). Returns the traced fans."""
    from matplotlib.patches import Polygon

    from ..lens.surface import sag
    from .analysis import footprint, ray_fans, surface_geometry

    fields = list(lens.fields_deg if fields is None else fields)
    wl = lens.primary_wavelength_nm if wavelength_nm is None else wavelength_nm
    par = lens.paraxial()
    # Surfaces without a clear aperture are sized by the rays of every field, drawn or not.
    geo = surface_geometry(lens, footprint(lens, set(fields) | set(lens.fields_deg), aiming))
    fans = ray_fans(lens, fields, rays, aiming, wl)
    z_img = par["image_z_mm"]
    z_first = min(
        g["z"] + float(np.nanmin(sag(g["surface"], np.linspace(-g["semi_diameter"], g["semi_diameter"], 41))))
        for g in geo[:1]
    )
    z_start = min(z_first, 0.0) - 0.15 * (z_img - min(z_first, 0.0))

    fig = Figure(dpi=130)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    # Elements (glass between surface i and i+1), then every surface profile.
    for a, b in zip(geo, geo[1:]):
        if a["glass_after"]:
            ax.add_patch(
                Polygon(
                    _element_outline(a, b, sag),
                    closed=True,
                    facecolor=(0.66, 0.83, 0.94, 0.6),
                    edgecolor="black",
                    linewidth=0.9,
                    zorder=1,
                )
            )
    for g in geo:
        r = np.linspace(-g["semi_diameter"], g["semi_diameter"], 121)
        ax.plot(g["z"] + sag(g["surface"], r), r, color="black", linewidth=0.9, zorder=2)
    # Aperture stop: blades from the stop radius outwards.
    st = next(g for g in geo if g["stop"])
    r_stop = st["semi_diameter"] if st["clear_aperture"] else par["stop_semi_diameter_mm"]
    z_stop = st["z"] + float(sag(st["surface"], r_stop))
    blade = max(0.35 * r_stop, 1.0)
    for sgn in (1, -1):
        ax.plot(
            [z_stop, z_stop],
            [sgn * r_stop, sgn * (r_stop + blade)],
            color="black",
            linewidth=3,
            zorder=4,
            solid_capstyle="butt",
        )
    ax.annotate("stop", (z_stop, r_stop + blade), textcoords="offset points", xytext=(0, 4), ha="center", fontsize=7)
    # Rays.
    y_max = max(g["semi_diameter"] for g in geo)
    for fan, colour in zip(fans, _field_colours(len(fans))):
        d = fan["direction"]
        for k, pts in enumerate(fan["rays"]):
            p0 = pts[0]
            t = (p0[0] - z_start) / d[2]
            zs, ys = np.r_[p0[0] - t * d[2], pts[:, 0]], np.r_[p0[1] - t * d[1], pts[:, 1]]
            note = (
                ""
                if fan["n_image"] == len(fan["status"])
                else f" ({fan['n_image']}/{len(fan['status'])} reach the image)"
            )
            ax.plot(
                zs,
                ys,
                color=colour,
                linewidth=0.7,
                zorder=3,
                label=f"{fan['field_deg']:g} deg{note}" if k == 0 else None,
            )
            if not fan["ok"][k]:  # failed ray: mark where it stopped
                ax.plot(zs[-1], ys[-1], marker="x", markersize=4, color=colour, zorder=5)
            y_max = max(y_max, float(np.max(np.abs(ys))))
    # Image plane over the image height reached by the rays.
    y_img = max([abs(float(p[-1, 1])) for f in fans for p in f["rays"] if abs(p[-1, 0] - z_img) < 1e-9] + [1.0])
    ax.plot([z_img, z_img], [-1.08 * y_img, 1.08 * y_img], color="black", linewidth=1.4, zorder=4)
    ax.annotate("image", (z_img, 1.08 * y_img), textcoords="offset points", xytext=(0, 4), ha="center", fontsize=7)
    ax.axhline(0.0, color="0.6", linewidth=0.5, linestyle=(0, (8, 4, 2, 4)), zorder=0)

    # Equal scales in z and y; the figure takes the shape of the drawing.
    pad = 0.04 * (z_img - z_start)
    ax.set_xlim(z_start - pad, z_img + pad)
    ax.set_ylim(-1.12 * y_max - pad, 1.12 * y_max + pad)
    ax.set_aspect("equal", adjustable="box")
    width = 10.0
    ratio = (2.24 * y_max + 2 * pad) / (z_img - z_start + 2 * pad)
    fig.set_size_inches(width, min(max(0.85 * width * ratio + 1.3, 3.0), 12.0))
    ax.set_xlabel("z (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(fontsize=7, loc="upper left", title="field", title_fontsize=7)
    flds = ", ".join(f"{f:g}" for f in fields)
    ax.set_title(
        f"{lens.name}: EFL {par['efl_mm']:.3f} mm, f/{par['f_number']:.2f}, fields {flds} deg "
        f"({wl:g} nm, {aiming} aiming, {rays} rays per field)",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)
    return {
        "fans": fans,
        "geometry": geo,
        "z_start": z_start,
        "xlim": ax.get_xlim(),
        "ylim": ax.get_ylim(),
        "size_px": tuple(int(v) for v in fig.canvas.get_width_height()),
    }


def _no_neg_zero(v: float, digits: int) -> str:
    text = f"{v:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def _panels(n: int, max_cols: int, width: float, height: float):
    """A figure of n panels (width x height inches each) in rows of at most max_cols, with
    room for a title; returns it and the flat array of axes (spare ones included)."""
    cols = min(n, max_cols)
    rows = -(-n // cols)
    fig = Figure(figsize=(width * cols, height * rows + 0.5), dpi=120)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, squeeze=False).ravel()


def save_spots_png(path: str | Path, lens, spots: Sequence[dict]) -> None:
    """One spot diagram per field on a common scale: rays coloured by wavelength,
    centred on the polychromatic centroid, RMS radius and the Airy disk (1.22 lambda N)."""
    from matplotlib.patches import Circle

    n = len(spots)
    fig, axes = _panels(n, max_cols=4, width=3.3, height=3.5)
    n_f = lens.paraxial()["f_number"]
    airy = 1.22 * lens.primary_wavelength_nm * 1e-3 * n_f
    half = max([airy] + [float(np.max(np.abs(p))) for s in spots for p in s["points_um"] if p.size]) * 1.1
    for ax, s in zip(axes, spots):
        for wl, p in zip(s["wavelengths_nm"], s["points_um"]):
            ax.scatter(p[:, 0], p[:, 1], s=1.5, color=wavelength_rgb(wl), label=f"{wl:g} nm", linewidths=0)
        ax.add_patch(Circle((0, 0), airy, fill=False, color="black", linewidth=0.8, linestyle="--"))
        ax.set_xlim(-half, half)
        ax.set_ylim(-half, half)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        ax.set_xlabel("x (um)", fontsize=8)
        ax.set_ylabel("y (um)", fontsize=8)
        ci = f", RI {s['relative_illumination']:.3f}" if s.get("relative_illumination") is not None else ""
        ax.set_title(
            f"{s['field_deg']:g} deg: RMS {s['rms_um']:.2f} um{ci}\n"
            f"centroid y {_no_neg_zero(s['centroid_um'][1] * 1e-3, 4)} mm",
            fontsize=8,
        )
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=6, loc="upper right", markerscale=4)
    fig.suptitle(
        f"{lens.name}: spot diagrams (centroid-referenced; dashed: Airy disk, radius {airy:.2f} um "
        f"at {lens.primary_wavelength_nm:g} nm, f/{n_f:.2f})",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)


def save_mtf_png(
    path: str | Path,
    lens,
    mtfs: Sequence[dict],
    per_wavelength: bool = False,
    mark_freq: float | None = None,
    max_freq: float | None = None,
) -> None:
    """Tangential (solid) and sagittal (dashed) MTF per field, polychromatic, with the
    diffraction limit; per-wavelength curves as thin lines when asked."""
    n = len(mtfs)
    fig, axes = _panels(n, max_cols=3, width=4.2, height=3.4)
    for ax, m in zip(axes, mtfs):
        f = m["freq_cyc_mm"]
        top = f[-1] if max_freq is None else max_freq
        ax.plot(f, m["diffraction_limit"], color="black", linewidth=0.9, label="diffraction limit")
        ax.plot(f, m["tangential"], color="C0", linewidth=1.4, label="T (poly)")
        ax.plot(f, m["sagittal"], color="C3", linewidth=1.4, linestyle="--", label="S (poly)")
        if per_wavelength:
            for p in m["per_wavelength"]:
                c = wavelength_rgb(p["wavelength_nm"])
                ax.plot(f, p["tangential"], color=c, linewidth=0.6, label=f"T {p['wavelength_nm']:g} nm")
                ax.plot(f, p["sagittal"], color=c, linewidth=0.6, linestyle="--")
        if mark_freq is not None and mark_freq <= top:
            ax.axvline(
                mark_freq, color="0.5", linewidth=0.7, linestyle=":", label=f"{mark_freq:.1f} c/mm (5.86 um Nyquist)"
            )
        ax.set_xlim(0, top)
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("spatial frequency (cycles/mm)", fontsize=8)
        ax.set_ylabel("MTF", fontsize=8)
        ax.set_title(f"{m['field_deg']:g} deg", fontsize=9)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=6, loc="upper right")
    wls = ", ".join(f"{w:g}" for w in lens.wavelengths_nm)
    wts = ", ".join(f"{w:g}" for w in lens.wavelength_weights)
    method = mtfs[0].get("method", "fft").upper() if mtfs else "FFT"
    fig.suptitle(
        f"{lens.name}: polychromatic MTF from {method} PSFs ({wls} nm, weights {wts}); T: tangential, S: sagittal",
        fontsize=9,
    )
    fig.tight_layout()
    save_figure(fig, path)
