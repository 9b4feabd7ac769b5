"""``optix metrics IMAGE REFERENCE``: PSNR, SSIM, LPIPS (AlexNet v0.1) and HaarPSI of an image
against a reference, offline."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ..io import require_regular_file
from ._common import device_option, dumps, friendly_errors

MAX_PIXELS = 64_000_000  # larger files are refused before they are decoded (a decompression bomb)


def _read(path: str):
    """An 8-bit or 16-bit image file -> float32 [3, H, W] in [0, 1] at the file's own depth
    (16-bit greyscale is scaled by 65535, not clipped at 255). One error for anything else."""
    import warnings

    import numpy as np
    import torch
    from PIL import Image, UnidentifiedImageError

    try:
        require_regular_file(path, "image")  # a FIFO would block the read for ever
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                w, h = im.size
                if w * h > MAX_PIXELS:
                    raise click.ClickException(
                        f"{path}: {w}x{h} pixels is more than this command reads ({MAX_PIXELS} pixels)"
                    )
                if im.mode.startswith("I;16") or im.mode == "I":
                    # 16-bit greyscale (Pillow opens some 16-bit files, PGM among them, as "I")
                    a = np.asarray(im, dtype=np.int64)
                    if a.min() < 0 or a.max() > 65535:
                        raise click.ClickException(
                            f"{path}: 32-bit integer values beyond 16 bits are not read; "
                            f"save it with 8 or 16 bits per channel"
                        )
                    a = np.repeat((a.astype(np.float32) / 65535.0)[:, :, None], 3, axis=2)
                elif im.mode == "F":
                    raise click.ClickException(
                        f"{path}: floating-point images are not read; save it with 8 or 16 bits per channel"
                    )
                else:
                    a = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise click.ClickException(f"{path}: too large to decode safely ({exc})") from None
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise click.ClickException(f"{path}: cannot read as an image ({exc})") from None
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)


@click.command("metrics")
@click.argument("image", type=click.Path(exists=True, dir_okay=False))
@click.argument("reference", type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--crop",
    type=click.IntRange(0, 100_000),
    default=0,
    show_default=True,
    help="Pixels dropped from every border before scoring.",
)
@device_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@friendly_errors
def metrics(image, reference, crop, device, as_json):
    """Quality of IMAGE against REFERENCE (8- or 16-bit sRGB files of one size): PSNR (dB), SSIM,
    LPIPS (AlexNet, v0.1; lower is closer; the paper reports 1 - LPIPS) and HaarPSI, computed
    on --device."""
    from ..device import resolve_device
    from ..metrics.image import summarize
    from ..metrics.lpips import LPIPS_MIN_SIZE, lpips

    dev = resolve_device(device)

    x, y = _read(image), _read(reference)
    if x.shape != y.shape:
        raise click.ClickException(
            f"{image} is {x.shape[2]}x{x.shape[1]} but {reference} is "
            f"{y.shape[2]}x{y.shape[1]}: the images must have one size"
        )
    if min(x.shape[1:]) - 2 * crop < LPIPS_MIN_SIZE:
        raise click.ClickException(
            f"images of {x.shape[2]}x{x.shape[1]} with --crop {crop} leave less than {LPIPS_MIN_SIZE}x"
            f"{LPIPS_MIN_SIZE} pixels (LPIPS's minimum: its AlexNet's windows; HaarPSI needs 16x16)"
        )
    x, y = x.to(dev), y.to(dev)
    out = summarize(x[None], y[None], crop=crop)
    xc, yc = (
        x[:, crop : x.shape[1] - crop, crop : x.shape[2] - crop],
        y[:, crop : y.shape[1] - crop, crop : y.shape[2] - crop],
    )
    out["lpips"] = float(lpips(xc[None], yc[None])[0])
    out = {
        "image": str(Path(image)),
        "reference": str(Path(reference)),
        "psnr_db": out["psnr_db"],
        "ssim": out["ssim"],
        "lpips": out["lpips"],
        "haarpsi": out["haarpsi"],
        "device": str(dev),
    }
    if as_json:
        click.echo(dumps(out))
        return
    psnr = "inf (identical)" if math.isinf(out["psnr_db"]) else f"{out['psnr_db']:.3f} dB"
    click.echo(
        f"PSNR {psnr}   SSIM {out['ssim']:.4f}   LPIPS {out['lpips']:.4f} (1 - LPIPS {1 - out['lpips']:.4f})"
        f"   HaarPSI {out['haarpsi']:.4f}"
    )
