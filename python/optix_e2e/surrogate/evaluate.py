"""Surrogate accuracy on held-out designs, per field and overall, and a PNG grid of predicted
against exact PSFs.

Per (design, field, channel), on the unit-sum PSFs (the vignetting is scored on its own):

* ``psf_rel_l1``: sum |psf - psf*| (the relative L1 error, the PSFs summing to 1),
* ``psf_rel_l2``: ||psf - psf*||_2 / ||psf*||_2,
* ``strehl_rel_err``: |peak - peak*| / peak*. The Strehl ratio is the peak over the
  diffraction-limited peak of the same design and pitch, so its relative error is the peak's;
* ``ee_abs_err``: max over radii of |EE(r) - EE*(r)|, EE the energy in pixels within r of
  the chief-ray pixel (r = 1 .. S/2 pixels), in units of the PSF's energy,
* ``vignetting_abs_err``: |v - v*| of the relative illumination.

Medians, means and 90th percentiles are over designs x channels per field, and over
everything for the overall figures.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from ..dataset.layout import differing_keys, read_manifest, shard_name, shards_dir
from ..dataset.manifest import back_focus_limit
from ..dataset.settings import DatasetSettings
from ..errors import InputError
from ..io import save_figure
from .checkpoint import OpticsSurrogate
from .data import load_arrays, psf_grid, psf_pitch_um
from .train import predict_all

METRICS = ("psf_rel_l1", "psf_rel_l2", "strehl_rel_err", "ee_abs_err", "vignetting_abs_err")


class SurrogateDataMismatch(InputError):
    """The dataset was made with other settings than the surrogate's training data."""


def check_compatible(model: OpticsSurrogate, man: dict, root) -> None:
    """The dataset must have the model's parameters, fields, channels and PSF grid."""
    names = [p["name"] for p in man["space"]["parameters"]]
    problems = []
    if names != model.param_names:
        problems.append(f"parameters {names} vs the model's {model.param_names}")
    if not np.allclose(man["fields_deg"], model.fields_deg):
        problems.append(f"fields {man['fields_deg']} vs {model.fields_deg}")
    if len(man["channels"]) != model.cfg.channels:
        problems.append(f"{len(man['channels'])} channels vs {model.cfg.channels}")
    trained = model.manifest
    if trained and differing_keys(man, trained, ["channels"]):
        problems.append("other channel wavelengths")
    try:
        size, pitch = psf_grid(man, model.psf_kind, model.bin), psf_pitch_um(man, model.psf_kind, model.bin)
        if size != model.cfg.psf_size or abs(pitch - model.pitch_um) > 1e-9:
            problems.append(
                f"{model.psf_kind} grid {size} px at {pitch} um vs {model.cfg.psf_size} px at {model.pitch_um} um"
            )
    except ValueError as exc:
        problems.append(str(exc))
    if trained:
        a, b = man.get("settings", {}), trained.get("settings", {})
        diff = differing_keys(a, b, (set(a) | set(b)) - {"shard_size"})
        if "focus_within" in diff and _focus_rules_agree(root, man):
            diff.remove("focus_within")
        if diff:
            at = DatasetSettings.recorded
            detail = ", ".join(f"{k}: {at(a, k)!r} here, {at(b, k)!r} in its training data" for k in diff)
            problems.append(f"dataset settings differ ({detail})")
    if problems:
        raise SurrogateDataMismatch(f"{root}: not data of this surrogate: " + "; ".join(problems))


def _focus_rules_agree(root, man: dict) -> bool:
    """Whether the focus rules ``focus_within`` "bfd" and "none" give this dataset's records
    alike: no design's image plane at or short of the space's back-focus limit (the only
    designs the rules treat differently)."""
    limit = back_focus_limit(man)
    if limit is None:
        return True
    for k in range(int(man.get("n_shards", 0))):  # the shards' own folders, not a writer's temporaries
        f = shards_dir(Path(root)) / shard_name(k) / "image_distance.npy"
        if not f.is_file():
            continue
        try:
            z = np.load(f, allow_pickle=False)
        except (OSError, ValueError):
            return False  # unreadable: not shown to agree (load_arrays names the damage)
        if np.any(z <= limit + 1e-9):
            return False
    return True


def _ee_curves(p: torch.Tensor) -> torch.Tensor:
    """Encircled energy about the centre pixel: [..., S, S] -> [..., R] for r = 1..S//2."""
    s = p.shape[-1]
    c = (s - 1) / 2 if s % 2 else s // 2
    yy, xx = torch.meshgrid(torch.arange(s) - c, torch.arange(s) - c, indexing="ij")
    rr = torch.hypot(yy, xx)
    radii = torch.arange(1, s // 2 + 1, dtype=rr.dtype)
    masks = (rr[None] <= radii[:, None, None]).to(p)  # [R, S, S]
    return torch.einsum("...ij,rij->...r", p, masks)


def sample_metrics(psf: torch.Tensor, vig: torch.Tensor, psf_true: torch.Tensor, vig_true: torch.Tensor) -> dict:
    """Per-(design, field, channel) metrics, each [N, K, C] (numpy)."""
    d = psf - psf_true
    peak_true = psf_true.amax((-2, -1))
    out = {
        "psf_rel_l1": d.abs().sum((-2, -1)),
        "psf_rel_l2": d.pow(2).sum((-2, -1)).sqrt() / psf_true.pow(2).sum((-2, -1)).sqrt(),
        "strehl_rel_err": (psf.amax((-2, -1)) - peak_true).abs() / peak_true,
        "ee_abs_err": (_ee_curves(psf) - _ee_curves(psf_true)).abs().amax(-1),
        "vignetting_abs_err": (vig - vig_true).abs(),
    }
    return {k: v.cpu().numpy() for k, v in out.items()}


def summarize(m: dict, fields_deg) -> dict:
    out = {"overall": {}, "per_field": []}
    for name in METRICS:
        v = m[name]
        out["overall"][name] = {
            "median": float(np.median(v)),
            "mean": float(np.mean(v)),
            "p90": float(np.percentile(v, 90)),
            "max": float(np.max(v)),
        }
    for j, f in enumerate(fields_deg):
        row = {"field_deg": float(f)}
        for name in METRICS:
            v = m[name][:, j]
            row[name] = {"median": float(np.median(v)), "mean": float(np.mean(v)), "p90": float(np.percentile(v, 90))}
        out["per_field"].append(row)
    return out


def f_number_bands(m: dict, f_numbers: np.ndarray, fields_deg, edges=(2.9, 3.3, 3.7, 4.1, 4.6)) -> list[dict]:
    """Median PSF relative L1 per field (and the vignetting error) for designs in each f-number band."""
    out = []
    f_numbers = np.asarray(f_numbers, float)
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f_numbers >= lo) & ((f_numbers < hi) if hi != edges[-1] else (f_numbers <= hi))
        if not sel.any():
            continue
        rel = m["psf_rel_l1"][sel]
        out.append(
            {
                "f_number": [lo, hi],
                "n_designs": int(sel.sum()),
                "psf_rel_l1_median": float(np.median(rel)),
                "psf_rel_l1_median_per_field": {
                    f"{f:g}": float(np.median(rel[:, j])) for j, f in enumerate(fields_deg)
                },
                "vignetting_abs_err_median": float(np.median(m["vignetting_abs_err"][sel])),
            }
        )
    return out


def evaluate(
    model: OpticsSurrogate,
    data_root,
    max_designs: int | None = None,
    png: "str | Path | None" = None,
    grid_designs: int = 3,
    grid_fields: int = 5,
) -> dict:
    """Score ``model`` on the designs of ``data_root`` it did not train on: all of them for
    another dataset, the held-out validation designs when it is the training dataset."""
    man = read_manifest(data_root)
    check_compatible(model, man, data_root)
    data = model.meta.get("data", {})
    same = data.get("designs_csv_sha256") == man["designs_csv_sha256"]
    designs = data.get("val_designs") if same else None
    if same and not designs:
        raise SurrogateDataMismatch(
            f"{data_root}: the model trained on every design of this dataset; "
            f"evaluate on another one (e.g. `optix dataset ... --seed 1`)"
        )
    if designs is not None and max_designs:
        designs = designs[:max_designs]
    arrays, _ = load_arrays(
        data_root, model.psf_kind, model.bin, designs=designs, max_designs=None if designs is not None else max_designs
    )
    # the designs go to the model's device (``optix surrogate eval --device``), the predictions
    # come back to the CPU, where the dataset's PSFs are and the metrics are computed
    dev = model.param_mean.device
    params = torch.as_tensor(arrays.params, dtype=torch.float32)
    problems = model.check_params(params, mode="ignore")
    model.eval()
    t0 = time.perf_counter()
    psf, vig = predict_all(model, params.to(dev))
    psf, vig = psf.cpu(), vig.cpu()  # (waits for the device: the time is the prediction's)
    seconds = time.perf_counter() - t0
    bad = ~(torch.isfinite(psf).flatten(1).all(1) & torch.isfinite(vig).flatten(1).all(1))
    if bad.any():
        raise InputError(
            f"the surrogate predicts non-finite PSFs or vignetting for {int(bad.sum())} of "
            f"{len(bad)} designs (damaged weights?); no metrics"
        )
    truth = torch.as_tensor(arrays.psf)
    dark = ~(truth.flatten(-2).sum(-1) > 0)  # a PSF with no light has no relative error (NaN)
    if dark.any():
        raise InputError(
            f"{data_root}: {int(dark.sum())} of the dataset's PSF channels hold no light (a damaged or "
            f"forged shard: `optix dataset verify {data_root}` names it); no metrics"
        )
    m = sample_metrics(psf, vig, truth, torch.as_tensor(arrays.vignetting))
    s = summarize(m, model.fields_deg)
    o = s["overall"]
    report = {
        "psf_rel_l1_median": o["psf_rel_l1"]["median"],
        "vignetting_abs_err_median": o["vignetting_abs_err"]["median"],
        "psf_rel_l2_median": o["psf_rel_l2"]["median"],
        "strehl_rel_err_median": o["strehl_rel_err"]["median"],
        "ee_abs_err_median": o["ee_abs_err"]["median"],
        **s,
        "n_designs": int(len(arrays)),
        "n_psfs": int(psf.shape[0] * psf.shape[1] * psf.shape[2]),
        "held_out": "validation designs of the training dataset" if same else "every design of another dataset",
        "out_of_range": problems,
        "psf": {"kind": model.psf_kind, "size": model.cfg.psf_size, "pitch_um": model.pitch_um},
        "predict_seconds": round(seconds, 3),
        "data": str(Path(data_root)),
        "model_training": {k: v for k, v in model.meta.get("training", {}).items() if k != "config"},
        "model_data": {k: v for k, v in data.items() if k != "val_designs"},
    }
    if "f_number" in model.param_names:  # a space with the aperture: accuracy per f-number band too
        report["per_f_number_band"] = f_number_bands(
            m, arrays.params[:, model.param_names.index("f_number")], model.fields_deg
        )
    if png:
        save_grid(png, model, arrays, psf.numpy(), m["psf_rel_l1"], grid_designs, grid_fields)
        report["png"] = str(png)
    return report


def save_grid(
    path, model: OpticsSurrogate, arrays, pred: np.ndarray, rel_l1: np.ndarray, n_designs: int = 3, n_fields: int = 5
) -> None:
    """Rows: designs x (exact, predicted, |difference| x 5); columns: fields. RGB composites
    scaled to each exact PSF's peak."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plotting import rgb_composite

    nd = min(n_designs, len(arrays))
    rows = np.linspace(0, len(arrays) - 1, nd).round().astype(int)
    k = len(model.fields_deg)
    cols = np.unique(np.linspace(0, k - 1, min(n_fields, k)).round().astype(int))
    fig = Figure(figsize=(2.0 * len(cols), 2.05 * 3 * nd + 0.5), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3 * nd, len(cols), squeeze=False)
    for a, i in enumerate(rows):
        for b, j in enumerate(cols):
            exact, guess = arrays.psf[i, j], pred[i, j]
            peak = float(exact.max()) or 1.0
            panels = [
                (exact, "exact"),
                (guess, f"surrogate, L1 {rel_l1[i, j].mean():.1%}"),
                (np.abs(guess - exact) * 5, "|diff| x 5"),
            ]
            for r, (img, label) in enumerate(panels):
                ax = axes[3 * a + r, b]
                ax.imshow(rgb_composite(np.clip(img / peak, 0, 1)), origin="lower", interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(f"design {int(arrays.design[i])}, {model.fields_deg[j]:.1f} deg\n{label}", fontsize=7)
    fig.suptitle(
        f"surrogate vs exact PSFs ({model.psf_kind}, {model.cfg.psf_size} px at {model.pitch_um:g} um; "
        f"RGB, linear, each exact PSF's peak = 1)",
        fontsize=9,
    )
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path)
