"""Files a design run leaves for a person to open: the exported lens (.zmx and JSON), checks
of the final design, PSF grids from the engine, image panels and the lens reports."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from ..dataset.manifest import nearest_image_plane, refocused_designs, space_and_base
from ..io import save_figure
from ..lens import Lens
from ..lens.zemax.writer import write_zmx
from ..lens_design.constraints import Limits, Manufacturability, apertures


def design_lens(manifest: dict, values, image_distance: float) -> dict:
    """The lens dict of a design as the engine traced it: the values written into the base
    lens, its image plane at the refocused distance."""
    return refocused_designs(manifest, np.asarray(values, np.float64)[None], [image_distance])[0]


def check_final_design(manifest: dict, values, image_distance: float) -> dict:
    """Inside the space, manufacturable under the dataset's limits, refocused (best focus)."""
    space, _ = space_and_base(manifest)
    d = design_lens(manifest, values, image_distance)
    outside = space.check_bounds(d)
    limits = Limits.from_dict(manifest.get("sampling_summary", {}).get("limits"))
    reasons = Manufacturability(limits).problems(d)  # the rule the sampler and the guard use
    return {
        "inside_space": not outside,
        "outside": outside,
        "manufacturable": not reasons,
        "manufacturability_problems": reasons,
        "limits": {k: getattr(limits, k) for k in limits.__dataclass_fields__},
        **focus_check(manifest, d),
        "image_distance_mm": float(image_distance),
        "focus": manifest["settings"]["focus"],
    }


def focus_check(manifest: dict, d: dict, tol_um: float = 2.0) -> dict:
    """Is the image plane at best focus? The dataset's criterion (mean polychromatic RMS spot
    squared over the fields, its channel wavelengths), evaluated again with a finer pupil (8
    rings, all K fields, where the dataset used 4 rings and 7 fields): the shift it still asks
    for (um) and whether that is within ``tol_um`` (the depth of focus at f/4.4 is about +-20 um)."""
    import json

    from ..lens_design.focus import best_focus_shift

    wavelengths = sorted({float(wl) for c in manifest["channels"] for wl, _ in c})
    try:
        shift_um = 1e3 * best_focus_shift(
            json.dumps(d),
            [float(f) for f in manifest["fields_deg"]],
            wavelengths,
            rings=8,
            aiming=manifest["settings"].get("aiming", "paraxial"),
        )
    except Exception as err:  # noqa: BLE001 - an untraceable lens is not refocused; say why
        return {"refocused": False, "focus_shift_um": None, "focus_error": " ".join(str(err).split())}
    # a plane at the dataset's back-focus limit asking to come nearer is the best one allowed
    nearest = nearest_image_plane(manifest)
    at_limit = nearest is not None and abs(float(d["surfaces"][-1]["thickness"]) - nearest) <= 1e-9 and shift_um < 0
    out = {"refocused": bool(abs(shift_um) <= tol_um or at_limit), "focus_shift_um": shift_um}
    return {**out, "at_back_focus_limit": True} if at_limit else out


def catalog_material(material):
    """A resolved material dict ("N-SF11 (schott)" with its formula) back to the catalog name
    it came from, when that name resolves to the very same formula (so a .zmx can name it);
    anything else is returned unchanged."""
    import re

    from ..lens import glass

    if not isinstance(material, dict) or "formula" not in material:
        return material
    m = re.fullmatch(r"\s*(.+?)\s+\((\w[\w-]*)\)\s*", str(material.get("name", "")))
    if not m:
        return material
    name, cat = m.groups()
    for spec in (name, {"glass": name, "catalog": cat}):
        try:
            g = glass.resolve(spec)
        except glass.GlassError:
            continue
        if (
            g.formula == material["formula"]
            and list(g.coefficients) == list(material["coefficients"])
            and g.catalog == cat
        ):
            return spec
    return material


def export_lens(manifest: dict, values, image_distance: float, stem: Path, name: str, description: str) -> dict:
    """stem.json and stem.zmx; returns their paths."""
    d = design_lens(manifest, values, image_distance)
    d["name"], d["description"] = name, description
    # traced with automatic apertures: write the footprint's; with the base lens's fixed clear
    # apertures (--apertures fixed): keep them, and give the stop (whose iris followed the
    # f-number) its footprint
    fixed = manifest["settings"].get("apertures") == "fixed"
    for s in d["surfaces"]:
        if not fixed:
            s.pop("semi_diameter", None)
        s["material"] = catalog_material(s.get("material", "air"))
    lens = Lens(d, source=name)
    sd = apertures(lens)
    for s, h in zip(d["surfaces"], sd):
        if s.get("semi_diameter") is None:  # rounded up: the written aperture passes every rim ray
            s["semi_diameter"] = math.ceil(float(h) * 1e4) / 1e4
    lens = Lens(d, source=name)
    json_path = lens.save(stem.with_suffix(".json"))
    zmx_path = write_zmx(lens.raw, stem.with_suffix(".zmx"), source=name, footprint=lens.zmx_footprint())
    return {"json": str(json_path), "zmx": str(zmx_path)}


def psf_rel_l1_per_field(a: torch.Tensor, b: torch.Tensor) -> list[float]:
    """Median over channels of sum|a - b| / sum|b| per field, PSFs [K, C, S, S]."""
    b = b.to(a.device)  # the engine's PSFs (CPU) against a model's on its device
    err = (a - b).abs().sum((-2, -1)) / b.abs().sum((-2, -1)).clamp_min(1e-12)
    return [float(x) for x in err.median(dim=1).values]


def save_psf_grids(path: Path, psf: torch.Tensor, fields_deg, pixel_um: float, title: str) -> None:
    from ..plotting import save_psf_grid

    save_psf_grid(path, psf.detach().cpu().numpy(), fields_deg, pixel_um, ["R", "G", "B"], title=title, log=True)


def save_panels(path: Path, rows: list[tuple[str, list[torch.Tensor]]], columns: list[str]) -> None:
    """A grid of images [3, H, W] in [0, 1]: one row per (label, images), one column per method."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n_r, n_c = len(rows), len(columns)
    fig = Figure(figsize=(3.0 * n_c, 3.1 * n_r), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_r, n_c, squeeze=False)
    for i, (label, imgs) in enumerate(rows):
        for j, img in enumerate(imgs):
            ax = axes[i][j]
            ax.imshow(img.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy(), interpolation="nearest")
            ax.set_xticks([]), ax.set_yticks([])
            if i == 0:
                ax.set_title(columns[j], fontsize=10)
            if j == 0:
                ax.set_ylabel(label, fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def write_design_outputs(out: Path, cfg, sur, nominal_values, final_values, exact: dict) -> tuple[dict, dict]:
    """A design run's lens outputs: both lenses exported (lens/end_to_end and lens/nominal,
    .json and .zmx, refocused as the dataset does), the final design's checks, and both
    lenses' exact PSF grids (psf_*.png). Returns (the exported end-to-end paths, checks)."""
    fields_deg = [float(f) for f in sur.manifest["fields_deg"]]
    (out / "lens").mkdir(exist_ok=True)
    desc = (
        f"end-to-end design for {cfg.task} ({cfg.optimizer}, budget {cfg.budget}, seed {cfg.seed}) in the space of "
        f"{sur.manifest['base_lens'].get('name', 'the base lens')}; made by optix design"
    )
    exported = export_lens(
        sur.manifest,
        np.asarray(final_values),
        exact["image_distance"][1],
        out / "lens" / "end_to_end",
        f"{cfg.task}-end-to-end",
        desc,
    )
    export_lens(
        sur.manifest,
        np.asarray(nominal_values),
        exact["image_distance"][0],
        out / "lens" / "nominal",
        "nominal",
        "the nominal design, refocused as the dataset does",
    )
    checks = check_final_design(sur.manifest, np.asarray(final_values), exact["image_distance"][1])
    pitch = float(sur.manifest["settings"]["sensor_pixel_um"]) * sur.bin
    save_psf_grids(out / "psf_nominal.png", exact["psf"][0], fields_deg, pitch, "nominal (engine)")
    save_psf_grids(out / "psf_end_to_end.png", exact["psf"][1], fields_deg, pitch, "end-to-end (engine)")
    return exported, checks
