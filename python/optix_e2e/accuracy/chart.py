"""Summaries and charts of the sweep: per setting, the median cost and error over the cases;
the Pareto front (no other setting both faster and more accurate); PNG charts."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..io import save_figure

METRICS = ("rel_l1", "rel_l2", "strehl_err", "ee80_err_um", "image_rel_l2")
METHOD_ORDER = ("geometric", "fft", "fft-fast", "huygens")


def summarize(rows: list[dict], experiment: str = "method") -> list[dict]:
    """One row per (method, setting): medians over the cases of time and every error, the
    worst rel_l1, the number of cases, and whether the setting is on the Pareto front of
    (median time, median rel_l1)."""
    groups = defaultdict(list)
    for r in rows:
        if r.get("experiment") == experiment and "time_s" in r and not r.get("error"):
            groups[(r["method"], r["setting"])].append(r)
    out = []
    for (method, setting), rs in groups.items():
        s = {
            "method": method,
            "setting": setting,
            "n_cases": len(rs),
            "time_s": float(np.median([r["time_s"] for r in rs])),
        }
        for m in METRICS:
            vals = [r[m] for r in rs if m in r and not (isinstance(r[m], float) and math.isnan(r[m]))]
            s[m] = float(np.median(vals)) if vals else float("nan")
        s["rel_l1_max"] = float(max(r.get("rel_l1_max", r["rel_l1"]) for r in rs))
        for key in ("pupil_samples", "pad", "n_wavelengths", "k_fields"):
            if key in rs[0]:
                s[key] = rs[0][key]
        out.append(s)
    mark_pareto(out)
    out.sort(key=lambda s: (METHOD_ORDER.index(s["method"]) if s["method"] in METHOD_ORDER else 9, s["time_s"]))
    return out


def mark_pareto(points: list[dict], x: str = "time_s", y: str = "rel_l1") -> None:
    """Set ``pareto`` on each point: True where no other point has both a smaller x and a
    smaller y (ties: the cheaper keeps it)."""
    order = sorted(points, key=lambda p: (p[x], p[y]))
    best = math.inf
    for p in order:
        p["pareto"] = bool(p[y] < best)
        best = min(best, p[y])


def plot_methods(summary: list[dict], path: Path, title: str) -> None:
    """Error against time, one curve per method (its settings by cost), for the PSF's
    relative L1 and the rendered image's relative L2; the Pareto front marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    colors = {"geometric": "tab:orange", "fft": "tab:blue", "fft-fast": "tab:green", "huygens": "tab:red"}
    for ax, metric, label in (
        (axes[0], "rel_l1", "PSF relative L1 error (median over cases)"),
        (axes[1], "image_rel_l2", "rendered test image relative L2 error (median)"),
    ):
        pts = [dict(p) for p in summary if np.isfinite(p[metric])]
        mark_pareto(pts, "time_s", metric)
        for method in METHOD_ORDER:
            ms = [p for p in pts if p["method"] == method]
            if not ms:
                continue
            if method == "fft":  # one curve per padding
                by_pad = defaultdict(list)
                for p in ms:
                    by_pad[p.get("pad") or "auto"].append(p)
                for pad, ps in sorted(by_pad.items(), key=lambda kv: str(kv[0])):
                    ps.sort(key=lambda p: p["pupil_samples"])
                    ax.plot(
                        [p["time_s"] for p in ps],
                        [p[metric] for p in ps],
                        "o-",
                        color=colors[method],
                        alpha=0.45 if pad != "auto" else 1.0,
                        label=f"fft grid {'auto' if pad == 'auto' else f'{pad}N'}",
                    )
            else:
                ms.sort(key=lambda p: p["pupil_samples"])
                ax.plot([p["time_s"] for p in ms], [p[metric] for p in ms], "o-", color=colors[method], label=method)
            for p in ms:
                ax.annotate(
                    str(p["pupil_samples"]),
                    (p["time_s"], p[metric]),
                    fontsize=6,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
        front = sorted((p for p in pts if p["pareto"]), key=lambda p: p["time_s"])
        ax.step([p["time_s"] for p in front], [p[metric] for p in front], where="post", color="k", lw=1, ls="--")
        ax.scatter(
            [p["time_s"] for p in front],
            [p[metric] for p in front],
            s=120,
            facecolors="none",
            edgecolors="k",
            label="Pareto front",
            zorder=5,
        )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per PSF (s, median)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)


def plot_sampling(spectral: list[dict], fields: list[dict], path: Path) -> None:
    """Error against wavelengths per channel and against field samples K."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    by = defaultdict(list)
    for r in spectral:
        by[(r["lens"], r["channel"])].append(r)
    for (lens, ch), rs in sorted(by.items()):
        rs.sort(key=lambda r: r["n_wavelengths"])
        axes[0].plot(
            [r["n_wavelengths"] for r in rs],
            [r["rel_l1"] for r in rs],
            "o-",
            color={"R": "tab:red", "G": "tab:green", "B": "tab:blue"}[ch],
            alpha=0.7,
            label=f"{lens} {ch}",
        )
    axes[0].set_xlabel("wavelengths per channel")
    axes[0].set_ylabel("channel PSF relative L1 vs 33 wavelengths")
    by = defaultdict(list)
    for r in fields:
        by[r["lens"]].append(r)
    for lens, rs in sorted(by.items()):
        rs.sort(key=lambda r: r["k_fields"])
        axes[1].plot([r["k_fields"] for r in rs], [r["rel_l1"] for r in rs], "o-", label=f"{lens} mean")
        axes[1].plot(
            [r["k_fields"] for r in rs], [r["rel_l1_max"] for r in rs], "x:", alpha=0.6, label=f"{lens} worst field"
        )
    axes[1].set_xlabel("field samples K (linear interpolation between them)")
    axes[1].set_ylabel("PSF relative L1 vs the PSF at each field")
    for ax in axes:
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
