"""``optix metrics IMAGE REFERENCE``: PSNR, SSIM, LPIPS (AlexNet v0.1) and HaarPSI of an image
against a reference, offline."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ._common import dumps, friendly_errors


def _read(path: str):
    import numpy as np
    import torch
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            a = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except (OSError, UnidentifiedImageError) as exc:
        raise click.ClickException(f"{path}: cannot read as an image ({exc})") from None
    return torch.from_numpy(a).permute(2, 0, 1)


@click.command("metrics")
@click.argument("image", type=click.Path(exists=True, dir_okay=False))
@click.argument("reference", type=click.Path(exists=True, dir_okay=False))
@click.option("--crop", type=click.IntRange(min=0), default=0, show_default=True,
              help="Pixels dropped from every border before scoring.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@friendly_errors
def metrics(image, reference, crop, as_json):
    """Quality of IMAGE against REFERENCE (8-bit sRGB files of one size): PSNR (dB), SSIM,
    LPIPS (AlexNet, v0.1; lower is closer; the paper reports 1 - LPIPS) and HaarPSI."""
    from ..metrics.lpips import lpips
    from ..metrics.image import summarize

    x, y = _read(image), _read(reference)
    if x.shape != y.shape:
        raise click.ClickException(f"{image} is {x.shape[2]}x{x.shape[1]} but {reference} is "
                                   f"{y.shape[2]}x{y.shape[1]}: the images must have one size")
    if min(x.shape[1:]) - 2 * crop < 16:
        raise click.ClickException(f"images of {x.shape[2]}x{x.shape[1]} with --crop {crop} leave less than "
                                   f"16x16 pixels (HaarPSI's minimum)")
    out = summarize(x[None], y[None], crop=crop)
    xc, yc = (x[:, crop:x.shape[1] - crop, crop:x.shape[2] - crop], y[:, crop:y.shape[1] - crop, crop:y.shape[2] - crop])
    out["lpips"] = float(lpips(xc[None], yc[None])[0])
    out = {"image": str(Path(image)), "reference": str(Path(reference)), "psnr_db": out["psnr_db"],
           "ssim": out["ssim"], "lpips": out["lpips"], "haarpsi": out["haarpsi"]}
    if as_json:
        click.echo(dumps(out))
        return
    psnr = "inf (identical)" if math.isinf(out["psnr_db"]) else f"{out['psnr_db']:.3f} dB"
    click.echo(f"PSNR {psnr}   SSIM {out['ssim']:.4f}   LPIPS {out['lpips']:.4f} (1 - LPIPS {1 - out['lpips']:.4f})"
               f"   HaarPSI {out['haarpsi']:.4f}")
