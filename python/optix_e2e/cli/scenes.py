"""``optix scenes street --out DIR -n N``: labelled street scenes as a COCO set (issue 19);
``optix scenes photos prepare SOURCE --from CHECKOUT --out DIR``: a corpus of real photographs
with its manifest (scenes/corpus.py)."""

from __future__ import annotations

import time

import click

from ._common import SEED, FiniteFloatRange, dumps, friendly_errors


@click.group("scenes")
def scenes():
    """Scenes that work offline: labelled street scenes for detection, corpora of photographs."""


MAX_SIDE = 4096  # a scene is drawn in memory at float32: 4096 x 4096 x 3 is 200 MB per buffer


def _size(ctx, param, value: str) -> tuple[int, int]:
    try:
        h, w = (int(x) for x in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"expected HxW, e.g. 256x384, got {value!r}") from None
    if h < 32 or w < 32 or h > MAX_SIDE or w > MAX_SIDE:
        raise click.BadParameter(f"each side from 32 to {MAX_SIDE} pixels, got {value!r}")
    return h, w


@scenes.command("street")
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder: images/ (8-bit sRGB PNG) and annotations.json (COCO).",
)
@click.option("-n", "n", type=click.IntRange(1, 1_000_000), required=True, help="Number of scenes.")
@click.option("--size", default="256x384", show_default=True, callback=_size, help="HxW pixels.")
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@friendly_errors
def street(out, n, size, seed, quiet):
    """Street scenes with vehicles, pedestrians, bikes and traffic lights, shadows and dusk
    (docs/detection.md); scene i of a seed is the same whatever N. Prints one JSON line."""
    import json
    from pathlib import Path

    from ..scenes.coco import write_street_coco

    t0 = time.perf_counter()
    ann = write_street_coco(out, n, size, seed, progress=not quiet)
    wall = time.perf_counter() - t0
    data = json.loads(Path(ann).read_text())
    per_class = {c["name"]: sum(a["category_id"] == c["id"] for a in data["annotations"]) for c in data["categories"]}
    click.echo(
        dumps(
            {
                "annotations": str(ann),
                "images": n,
                "objects": len(data["annotations"]),
                "per_class": per_class,
                "wall_s": round(wall, 2),
                "scenes_per_s": round(n / wall, 2),
            }
        )
    )


@scenes.group("photos")
def photos():
    """Corpora of real photographs: the ISP's training photographs and the untouched test split."""


@photos.command("sources")
@friendly_errors
def photo_sources():
    """The named sources: where each is published, its licence and its role (one JSON line each)."""
    from ..scenes.corpus import SOURCES

    for name, src in sorted(SOURCES.items()):
        click.echo(dumps({"source": name, **src.__dict__}))


@photos.command("prepare")
@click.argument("source")
@click.option(
    "--from",
    "checkout",
    type=click.Path(file_okay=False),
    required=True,
    help="A local checkout of the source (`optix scenes photos sources` says where each is published).",
)
@click.option("--out", type=click.Path(file_okay=False), required=True, help="Folder: images/ and manifest.json.")
@click.option("--licence", default=None, help="SOURCE folder only: the terms your photographs may be used under.")
@click.option(
    "--role", type=click.Choice(["train", "test"]), default=None, help="SOURCE folder only: train (default) or test."
)
@click.option(
    "--val-fraction",
    type=FiniteFloatRange(0, 0.9),
    default=0.1,
    show_default=True,
    help="Share of a training corpus held back for validation (chosen by each file's sha256).",
)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@friendly_errors
def photo_prepare(source, checkout, out, licence, role, val_fraction, quiet):
    """Copy SOURCE's photographs (a name of `optix scenes photos sources`, or `folder` for your
    own) into --out with a manifest of each file's origin, size, sha256 and split, and the
    source's licence. Prints one JSON line."""
    from ..scenes.corpus import prepare_corpus

    m = prepare_corpus(source, checkout, out, licence=licence, role=role, val_fraction=val_fraction, progress=not quiet)
    click.echo(dumps({"out": out, **{k: m[k] for k in ("source", "role", "counts", "digest", "licence")}}))
