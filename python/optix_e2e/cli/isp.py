"""``optix isp ...``: the reference ISP, its learned proxy and the software ISP.

train-proxy     train the proxy on procedural scenes (TensorBoard logs in OUT/tb)
eval [PROXY]    proxy fidelity on held-out photos and hyperparameters (default: shipped proxy)
tune            tune the ISP hyperparameters through the proxy; check with the true ISP
train-software  train the software ISP (RAW -> ideal rendering)
params          the hyperparameters, their ranges and defaults
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from ._common import SEED, THREADS, FiniteFloatRange, device_option, dumps, friendly_errors, precision_option

OUT = click.Path(file_okay=False, path_type=Path)


@click.group("isp")
def isp():
    """Reference "hardware" ISP, its differentiable proxy, and the software ISP."""


def _train_options(fn):
    for opt in reversed(
        [
            click.option("--out", "out_dir", type=OUT, required=True, help="Output directory."),
            click.option("--steps", type=click.IntRange(1, 10_000_000), default=8000, show_default=True),
            click.option(
                "--minutes",
                type=FiniteFloatRange(min=0),
                default=0.0,
                show_default=True,
                help="Wall-time budget; the learning rate anneals over it (0 = no limit).",
            ),
            click.option("--batch", type=click.IntRange(1, 1024), default=16, show_default=True),
            click.option(
                "--patch",
                type=click.IntRange(16, 1024),
                default=64,
                show_default=True,
                help="Training patch size (px, multiple of 16).",
            ),
            click.option(
                "--pool",
                type=click.IntRange(16, 65536),
                default=3072,
                show_default=True,
                help="Training pairs per pool; a fresh pool every --refresh steps.",
            ),
            click.option(
                "--refresh", "refresh_every", type=click.IntRange(1, 10_000_000), default=1500, show_default=True
            ),
            click.option("--lr", type=FiniteFloatRange(min=0, min_open=True), default=1e-3, show_default=True),
            click.option(
                "--perceptual-weight",
                type=FiniteFloatRange(min=0),
                default=0.1,
                show_default=True,
                help="Weight of the perceptual term (1 - HaarPSI) next to L1.",
            ),
            click.option(
                "--base",
                type=click.IntRange(4, 256),
                default=32,
                show_default=True,
                help="UNet width (channels of the first level).",
            ),
            click.option("--seed", type=SEED, default=0, show_default=True),
            click.option("--threads", type=THREADS, default=0, help="torch threads (0 = default)."),
            device_option,
            precision_option,
            click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON."),
        ]
    ):
        fn = opt(fn)
    return fn


def _config(kw):
    from ..isp.train import TrainConfig

    if kw["patch"] % 16:
        raise click.BadParameter(f"{kw['patch']} is not a multiple of 16", param_hint="--patch")
    return TrainConfig(
        **{
            k: kw[k]
            for k in (
                "steps",
                "minutes",
                "batch",
                "patch",
                "pool",
                "refresh_every",
                "lr",
                "perceptual_weight",
                "base",
                "seed",
                "threads",
                "device",
                "precision",
            )
        }
    )


def _report(summary: dict, as_json: bool, out_dir: Path, name: str) -> None:
    if as_json:
        click.echo(dumps({k: v for k, v in summary.items() if k != "history"}))
        return
    val = summary["final_val"] or {}
    click.echo(
        f"{summary['steps_done']} steps in {summary['seconds']:.0f} s; validation "
        f"PSNR {val.get('psnr_db', float('nan')):.2f} dB, SSIM {val.get('ssim', float('nan')):.4f}"
    )
    click.echo(f"wrote {out_dir / name}, {out_dir / 'train.json'}, TensorBoard logs in {out_dir / 'tb'}")


#: a key each ISP command's JSON holds and no other command's file of the same name does
#: (``detect tune`` writes a tune.json too)
OWN_KEY = {"tune.json": "tuned_params"}


def _claim(out_dir: Path | None, name: str) -> None:
    """Refuse an --out that holds files other than ``name``, or a ``name`` another command
    wrote, before any work is done."""
    if out_dir is not None:
        from ..io import claim_out_dir, json_holds

        key = OWN_KEY.get(name)
        own = None if key is None else (lambda d: json_holds(d / name, key))
        claim_out_dir(out_dir, f"ISP {name}", {name}, own=own)


def _emit(res: dict, out_dir: Path | None, name: str, as_json: bool) -> bool:
    """Write OUT/name if asked (claimed by :func:`_claim` first); print the JSON if asked.
    True when the JSON was printed."""
    if out_dir is not None:
        from ..io import write_text_atomic

        out_dir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out_dir / name, dumps(res, indent=2))
    if as_json:
        click.echo(dumps(res))
    return as_json


@isp.command("train-proxy")
@_train_options
@click.option(
    "--init",
    type=click.Path(dir_okay=False, exists=True, path_type=Path),
    default=None,
    help="Continue training this proxy checkpoint.",
)
@friendly_errors
def train_proxy_cmd(out_dir, as_json, init, **kw):
    """Train the ISP proxy (Tseng et al. 2019) to imitate the reference ISP (L1 + perceptual).

    The shipped proxy was trained with --minutes 45, then continued with --init, --lr 4e-4,
    --seed 1 and --minutes 35 (the exact commands are in docs/isp.md)."""
    from ..isp.train import train_proxy

    summary = train_proxy(_config(kw), out_dir, init=init)
    _report(summary, as_json, out_dir, "proxy.pt")


@isp.command("train-software")
@click.option(
    "--out",
    "out_dir",
    type=OUT,
    required=True,
    help="Run directory (state.pt, software_isp.pt, curve.csv, tb/); the same command continues it.",
)
@click.option("--steps", type=click.IntRange(1, 10_000_000), default=200_000, show_default=True)
@click.option(
    "--minutes",
    type=FiniteFloatRange(min=0, max=1e6),
    default=0.0,
    show_default=True,
    help="Stop after this wall time in this call (0 = no limit); state.pt resumes it.",
)
@click.option(
    "--anneal-minutes",
    type=FiniteFloatRange(min=0, max=1e6),
    default=0.0,
    show_default=True,
    help="The cosine learning-rate decay ends after this much training time (0: at --steps).",
)
@click.option("--batch", type=click.IntRange(1, 256), default=8, show_default=True)
@click.option(
    "--crop",
    type=click.IntRange(32, 512),
    default=128,
    show_default=True,
    help="Sensor pixels per side of a training crop (a multiple of 16).",
)
@click.option(
    "--pool",
    type=click.IntRange(8, 65536),
    default=256,
    show_default=True,
    help="Samples made at a time; a fresh pool every --pool-steps steps.",
)
@click.option("--pool-steps", type=click.IntRange(1, 1_000_000), default=160, show_default=True)
@click.option("--lr", type=FiniteFloatRange(min=0, max=1, min_open=True), default=5e-4, show_default=True)
@click.option("--arch", type=click.Choice(["nafnet", "unet"]), default="nafnet", show_default=True)
@click.option(
    "--width", type=click.IntRange(4, 256), default=32, show_default=True, help="Channels of the network's first level."
)
@click.option("--depth", type=click.IntRange(1, 5), default=3, show_default=True)
@click.option("--blocks", type=click.IntRange(1, 8), default=1, show_default=True, help="NAF blocks per level.")
@click.option(
    "--no-position", "position", flag_value=False, default=True, help="Do not give the network the field position."
)
@click.option(
    "--surrogate",
    default="paper-triplet-e2e",
    show_default=True,
    help="The optics surrogate whose space the training lenses are drawn from.",
)
@click.option(
    "--low-light",
    type=FiniteFloatRange(0, 1),
    default=0.3,
    show_default=True,
    help="Fraction of samples at low light (exposure / 100, gain x 100).",
)
@click.option("--val-every", type=click.IntRange(1, 1_000_000), default=500, show_default=True)
@click.option("--val-size", type=click.IntRange(1, 100_000), default=48, show_default=True, help="Validation samples.")
@click.option(
    "--photos",
    type=click.Path(file_okay=False, exists=True),
    multiple=True,
    help="A photo corpus folder (`optix scenes photos prepare`; repeatable): its train split trains, its val "
    "split validates, and its crops are most of the scenes.",
)
@click.option(
    "--lpips-weight",
    type=FiniteFloatRange(min=0, max=100),
    default=0.0,
    show_default=True,
    help="Loss = L1 + this x LPIPS (the design runs fine-tune with 1).",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--threads", type=THREADS, default=0, help="torch threads (0 = default).")
@device_option
@precision_option
@click.option(
    "--init",
    type=click.Path(dir_okay=False, exists=True, path_type=Path),
    default=None,
    help="Start a new run from this software ISP's weights (e.g. the shipped one).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@friendly_errors
def train_software_cmd(out_dir, as_json, crop, init, **kw):
    """Pre-train the software ISP on RAW through lenses of the design space (docs/isp.md)."""
    from ..camera_design.isp_pretraining import PretrainConfig, pretrain

    if crop % 16:
        raise click.BadParameter(f"must be a multiple of 16, got {crop}", param_hint="--crop")
    kw["photos"] = tuple(kw["photos"])
    meta = pretrain(PretrainConfig(crop=crop, **kw), out_dir, init=init)
    if as_json:
        click.echo(dumps({k: v for k, v in meta.items() if k != "config"}))
    else:
        last = meta["curve"][-1] if meta["curve"] else {}
        click.echo(
            f"{meta['steps']} steps, {meta['minutes']} min; validation PSNR {last.get('psnr_db', 'n/a')} dB; "
            f"wrote {out_dir / 'software_isp.pt'}"
        )


@isp.command("eval")
@click.argument("proxy", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--size", type=click.IntRange(32, 4096), default=256, show_default=True, help="Photo size (px).")
@click.option(
    "--param-sets",
    type=click.IntRange(0, 256),
    default=4,
    show_default=True,
    help="Random held-out hyperparameter sets per photo (plus the defaults).",
)
@click.option("--photo", "photos", multiple=True, help="Restrict to these bundled photos (repeatable).")
@click.option("--out", "out_dir", type=OUT, default=None, help="Write eval.json here.")
@device_option
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
@friendly_errors
def eval_cmd(proxy, size, param_sets, photos, out_dir, device, as_json):
    """Proxy fidelity against the true ISP on held-out photos and hyperparameters.

    PROXY defaults to the proxy shipped inside the package. The proxy runs on --device; the
    reference ISP and the metrics on the CPU."""
    from ..device import resolve_device
    from ..isp.evaluate import evaluate_proxy
    from ..isp.proxy import BUNDLED, ISPProxy

    dev = resolve_device(device)
    _claim(out_dir, "eval.json")
    model = ISPProxy.load(proxy).to(dev)
    res = evaluate_proxy(model, size=size, n_param_sets=param_sets, photos=list(photos) or None)
    res["proxy"] = str(proxy or BUNDLED)
    res["device"] = str(dev)
    if _emit(res, out_dir, "eval.json", as_json):
        return
    click.echo(
        f"proxy {res['proxy']}: PSNR {res['proxy_psnr_db']:.2f} dB (min {res['min_psnr_db']:.2f}), "
        f"SSIM {res['proxy_ssim']:.4f}, HaarPSI {res['proxy_haarpsi']:.4f} over "
        f"{res['n_photos']} photos x {res['n_param_sets']} hyperparameter sets"
    )


@isp.command("tune")
@click.option(
    "--proxy",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Proxy checkpoint (default: the shipped one).",
)
@click.option("--steps", type=click.IntRange(1, 10_000_000), default=200, show_default=True)
@click.option(
    "--scenes",
    "n_scenes",
    type=click.IntRange(1, 4096),
    default=48,
    show_default=True,
    help="Procedural training scenes to tune on.",
)
@click.option("--perceptual-weight", type=FiniteFloatRange(min=0), default=1.0, show_default=True)
@click.option(
    "--size",
    type=click.IntRange(32, 4096),
    default=256,
    show_default=True,
    help="Held-out photo size for the true-ISP check.",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--out", "out_dir", type=OUT, default=None, help="Write tune.json here.")
@device_option
@click.option("--json", "as_json", is_flag=True)
@friendly_errors
def tune_cmd(proxy, steps, n_scenes, perceptual_weight, size, seed, out_dir, device, as_json):
    """Optimize the ISP hyperparameters through the proxy for image quality (L1 + perceptual
    against the ideal rendering), then compare default and tuned settings on the TRUE ISP over
    held-out photos."""
    from ..device import resolve_device
    from ..isp import params as hp
    from ..isp.proxy import ISPProxy
    from ..isp.tune import true_isp_quality, tune_params

    dev = resolve_device(device)
    _claim(out_dir, "tune.json")
    model = ISPProxy.load(proxy).to(dev)
    tuned, history = tune_params(model, steps=steps, n_scenes=n_scenes, perceptual_weight=perceptual_weight, seed=seed)
    before, after = true_isp_quality(hp.defaults(), size=size), true_isp_quality(tuned, size=size)
    res = {
        "default_params": hp.describe(hp.defaults()),
        "tuned_params": hp.describe(tuned),
        "true_isp_default": before,
        "true_isp_tuned": after,
        "improvement": {k: after[k] - before[k] for k in ("psnr_db", "ssim", "haarpsi")},
        "loss_first": history[0],
        "loss_last": history[-1],
        "steps": steps,
        "seed": seed,
        "device": str(dev),
    }
    if _emit(res, out_dir, "tune.json", as_json):
        return
    for label, r in (("default", before), ("tuned", after)):
        click.echo(
            f"true ISP, {label:7s}: PSNR {r['psnr_db']:.2f} dB, SSIM {r['ssim']:.4f}, HaarPSI {r['haarpsi']:.4f}"
        )
    click.echo("tuned: " + json.dumps(hp.describe(tuned)))


@isp.command("params")
@click.option("--json", "as_json", is_flag=True)
def params_cmd(as_json):
    """List the reference ISP's hyperparameters with their ranges and defaults."""
    from ..isp.params import SPACE

    rows = [
        {
            "name": p.name,
            "low": p.low,
            "high": p.high,
            "default": p.default,
            "unit": p.unit,
            "choices": list(p.choices),
            "doc": p.doc,
        }
        for p in SPACE
    ]
    if as_json:
        click.echo(dumps(rows))
        return
    for r in rows:
        rng = "|".join(r["choices"]) if r["choices"] else f"[{r['low']:g}, {r['high']:g}] {r['unit']}"
        click.echo(f"{r['name']:18s} {rng:24s} default {r['default']:g}  {r['doc']}")
