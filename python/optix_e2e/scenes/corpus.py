"""A corpus of real photographs at camera scale: prepared once from a named public source into
a folder with a manifest, then cropped at the photographs' native resolution.

``prepare_corpus`` copies a source's image files byte for byte into ``OUT/images/`` and writes
``OUT/manifest.json``: the source (where it is published and which folders were taken), its
licence, the corpus's role, and per file its origin, size, sha256 and split. ``PhotoCorpus``
loads one or more prepared folders, checks every file against its digest, and draws random
views (crop at native scale, flips, 90-degree turns); the exposure is the caller's (the
training streams draw a scene white per sample).

Roles keep the data honest:

* ``train`` corpora split their files into ``train`` and ``val`` (a fixed fraction, chosen
  from each file's sha256, so the split does not depend on file order or machine);
* ``test`` corpora are the untouched test split (docs/test-split.md): loading one for training
  or validation is refused.

The named sources (``SOURCES``) are public repositories whose files are read from a local
checkout (nothing is downloaded here). Standard test sets are used only as ``test``: BSDS500's
``val`` folder, which is BSD100 and holds CBSD68, is not part of the ``bsds500`` training
source.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError

__all__ = ["SOURCES", "Source", "prepare_corpus", "PhotoCorpus", "MANIFEST", "FORMAT"]

FORMAT = "optix-photo-corpus/1"
MANIFEST = "manifest.json"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
ROLES = ("train", "test")
VAL_FRACTION = 0.1


@dataclass(frozen=True)
class Source:
    published: str  # where the files are published
    folders: tuple[str, ...]  # folders of that checkout whose images are taken
    licence: str
    role: str  # "train" or "test"
    content: str


SOURCES: dict[str, Source] = {
    "bsds500": Source(
        published="https://github.com/BIDS/BSDS500 (mirror of the Berkeley Segmentation Data Set, January 2013)",
        folders=("BSDS500/data/images/train", "BSDS500/data/images/test"),
        licence="Berkeley Segmentation Data Set and Benchmarks: images made available by the UC Berkeley "
        "Computer Vision Group for non-commercial research and educational use (Martin et al. 2001, "
        "Arbelaez et al. 2011); used here to train research models, not redistributed",
        role="train",
        content="400 colour photographs (481 x 321 or 321 x 481): landscapes, animals, people, buildings, "
        "objects; its val folder (BSD100, the source of CBSD68) is left out: a standard test set",
    ),
    "kodak24": Source(
        published="https://github.com/cszn/FFDNet, testsets/Kodak24 (the Kodak Lossless True Color Image Suite)",
        folders=("testsets/Kodak24",),
        licence="Kodak Lossless True Color Image Suite: released by the Eastman Kodak Company for unrestricted "
        "usage; evaluated here, not redistributed",
        role="test",
        content="24 photographs of 768 x 512 (film scans): people, houses, boats, landscapes",
    ),
    "mcmaster18": Source(
        published="https://github.com/JingyunLiang/SwinIR, testsets/McMaster (Zhang, Wu, Buades and Li 2011)",
        folders=("testsets/McMaster",),
        licence="McMaster colour demosaicking test set (Zhang et al., J. Electron. Imaging 2011), "
        "published for research; evaluated here, not redistributed",
        role="test",
        content="18 crops of 500 x 500 from digital photographs: saturated colours, fine detail",
    ),
}


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _decode(path: Path) -> np.ndarray:
    """An image file -> uint8 [H, W, 3]; one InputError naming the file when it cannot be read."""
    import imageio.v3 as iio

    try:
        a = np.asarray(iio.imread(path, index=0))
    except Exception as err:  # imageio raises OSError, ValueError, SyntaxError, ... per plugin
        raise InputError(f"cannot read image {path}: {err}") from err
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or a.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{path}: not an 8- or 16-bit grey or colour image ({a.shape}, {a.dtype})")
    if a.dtype == np.uint16:
        a = (a.astype(np.float32) / 257.0).round().astype(np.uint8)
    return np.ascontiguousarray(a[:, :, :3] if a.shape[2] >= 3 else a.repeat(3, axis=2))


def _split_of(sha: str, role: str, val_fraction: float) -> str:
    if role == "test":
        return "test"
    return "val" if int(sha[:8], 16) < val_fraction * 16**8 else "train"


def corpus_digest(files: list[dict]) -> str:
    """sha256 over the sorted (file, sha256, split) rows: names the corpus in a run's records."""
    rows = sorted(f"{f['file']} {f['sha256']} {f['split']}" for f in files)
    return hashlib.sha256("\n".join(rows).encode()).hexdigest()


def prepare_corpus(
    source: str,
    checkout: "str | Path",
    out: "str | Path",
    *,
    licence: str | None = None,
    role: str | None = None,
    val_fraction: float = VAL_FRACTION,
    min_side: int = 160,
    progress: bool = False,
) -> dict:
    """Copy the images of ``source`` found in ``checkout`` into ``out`` with a manifest.

    ``source`` is a name of ``SOURCES`` (its folders, licence and role are fixed), or
    ``"folder"``: every image under ``checkout``, with ``licence`` (required) and ``role``
    given. Every file is decoded once (an unreadable one stops the preparation, naming it);
    images whose shorter side is under ``min_side`` pixels are refused (a training crop with
    its margin would not fit). ``out`` must be new, empty, or this same preparation (it is
    then checked and rewritten). Returns the manifest."""
    import shutil

    from tqdm import tqdm

    from ..io import claim_out_dir, write_json_atomic

    checkout, out = Path(checkout), Path(out)
    if source == "folder":
        if not licence or not licence.strip():
            raise InputError("a folder of your own photographs needs --licence: the terms the files may be used under")
        role = role or "train"
        if role not in ROLES:
            raise InputError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
        src = Source(str(checkout.resolve()), (".",), licence.strip(), role, "the user's photographs")
    elif source in SOURCES:
        src = SOURCES[source]
        if licence is not None or role is not None:
            raise InputError(f"source {source!r} has its own licence and role ({src.role}); give neither")
    else:
        raise InputError(f"unknown photo source {source!r}; known: {', '.join(sorted(SOURCES))}, folder")
    if not 0 <= val_fraction < 1:
        raise InputError(f"val_fraction must be in [0, 1), got {val_fraction}")
    if not checkout.is_dir():
        raise InputError(f"{checkout}: no such folder (a checkout of {src.published})")
    paths, names = [], []
    for folder in src.folders:
        d = checkout / folder
        if not d.is_dir():
            raise InputError(f"{checkout} has no folder {folder}: not a checkout of {src.published}")
        found = sorted(p for p in d.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        paths += found
        # images/<the folder's last part>/<path inside it>: files of two folders never collide
        names += [(Path("images") / Path(folder).name / p.relative_to(d)).as_posix() for p in found]
    if not paths:
        raise InputError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {', '.join(src.folders)} under {checkout}")
    claim_out_dir(out, "photo corpus", {"images", MANIFEST}, marker=MANIFEST)
    files = []
    for p, name in tqdm(list(zip(paths, names)), desc=f"photos from {source}", unit="img", disable=not progress):
        a = _decode(p)
        if min(a.shape[:2]) < min_side:
            raise InputError(f"{p}: {a.shape[0]} x {a.shape[1]} pixels, under the {min_side} a training crop needs")
        sha = _sha256(p)
        files.append(
            {
                "file": name,
                "origin": p.relative_to(checkout).as_posix(),
                "sha256": sha,
                "height": int(a.shape[0]),
                "width": int(a.shape[1]),
                "split": _split_of(sha, src.role, val_fraction),
            }
        )
    if len(set(names)) != len(names):
        raise InputError(f"{checkout}: two images map to one name in the corpus; rename one of them")
    for f, p in zip(files, paths):
        dst = out / f["file"]
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.tmp")
        shutil.copyfile(p, tmp)
        tmp.replace(dst)
    manifest = {
        "format": FORMAT,
        "source": source,
        "published": src.published,
        "folders": list(src.folders),
        "licence": src.licence,
        "content": src.content,
        "role": src.role,
        "val_fraction": val_fraction if src.role == "train" else 0.0,
        "counts": {s: sum(f["split"] == s for f in files) for s in ("train", "val", "test")},
        "digest": corpus_digest(files),
        "files": files,
    }
    write_json_atomic(out / MANIFEST, manifest)  # written last: a folder without it is no corpus
    return manifest


def read_manifest(root: "str | Path") -> dict:
    from ..io import read_small_text

    root = Path(root)
    path = root / MANIFEST
    if not path.is_file():
        raise InputError(f"{root}: no {MANIFEST}; prepare the folder with `optix scenes photos prepare`")
    try:
        m = json.loads(read_small_text(path, 64 << 20, "photo corpus manifest"))
    except json.JSONDecodeError as err:
        raise InputError(f"{path}: not JSON ({err})") from None
    if not isinstance(m, dict) or m.get("format") != FORMAT or not isinstance(m.get("files"), list):
        raise InputError(f"{path}: not a photo corpus manifest ({FORMAT})")
    if m.get("role") not in ROLES:
        raise InputError(f"{path}: role {m.get('role')!r} is not one of {', '.join(ROLES)}")
    return m


class PhotoCorpus:
    """The photographs of one split (``train``, ``val`` or ``test``) of prepared corpus folders,
    decoded once into uint8 [3, H, W] tensors after each file is checked against its sha256.

    ``view(h, w, rng)`` is a random crop at native scale (float32 sRGB in [0, 1]), after a
    random 90-degree turn and flips; a photo too small for the crop in both orientations is
    never drawn for it (none at all: one InputError)."""

    def __init__(self, roots, split: str = "train", *, verify: bool = True):
        if split not in ("train", "val", "test"):
            raise InputError(f"split must be train, val or test, got {split!r}")
        roots = [Path(r) for r in ([roots] if isinstance(roots, (str, Path)) else roots)]
        if not roots:
            raise InputError("no photo corpus folder given")
        self.split, self.images, self.names, self.manifests = split, [], [], []
        self._fit_cache: dict[tuple[int, int], list[int]] = {}
        for root in roots:
            m = read_manifest(root)
            if (m["role"] == "test") != (split == "test"):
                what = "the untouched test split" if m["role"] == "test" else "a training corpus"
                raise InputError(f"{root} holds {what} ({m['source']}); it cannot give {split} photographs")
            self.manifests.append(m)
            for f in m["files"]:
                if not isinstance(f, dict) or not {"file", "sha256", "split"} <= set(f):
                    raise InputError(f"{root / MANIFEST}: a file entry without file, sha256 and split")
                if f["split"] != split:
                    continue
                path = root / f["file"]
                if not path.is_file():
                    raise InputError(f"{path}: listed in {root / MANIFEST} but missing")
                if verify and _sha256(path) != f["sha256"]:
                    raise InputError(f"{path}: its sha256 differs from the manifest's (changed since prepared)")
                self.images.append(torch.from_numpy(_decode(path)).permute(2, 0, 1).contiguous())
                self.names.append(f"{m['source']}:{f['file']}")
        if not self.images:
            raise InputError(f"no {split} photographs in {', '.join(map(str, roots))}")
        self.digest = hashlib.sha256(" ".join(m["digest"] for m in self.manifests).encode()).hexdigest()

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, i: int) -> torch.Tensor:
        return self.images[i].float() / 255.0

    def record(self) -> dict:
        """What a run writes down about the photographs it used."""
        return {
            "split": self.split,
            "photos": len(self),
            "digest": self.digest,
            "sources": [{k: m[k] for k in ("source", "published", "licence", "digest")} for m in self.manifests],
        }

    def _fits(self, h: int, w: int) -> list[int]:
        key = (h, w)
        if key not in self._fit_cache:
            self._fit_cache[key] = [
                i
                for i, im in enumerate(self.images)
                if min(im.shape[1:]) >= min(h, w) and max(im.shape[1:]) >= max(h, w)
            ]
        return self._fit_cache[key]

    def view(self, h: int, w: int, rng: np.random.Generator) -> torch.Tensor:
        fits = self._fits(h, w)
        if not fits:
            raise InputError(f"no photograph of the corpus holds a {h} x {w} crop at native scale")
        img = self.images[fits[int(rng.integers(len(fits)))]]
        turns = [t for t in (False, True) if img.shape[2 if t else 1] >= h and img.shape[1 if t else 2] >= w]
        if turns[int(rng.integers(len(turns)))]:  # a 90-degree turn (with the flips below: all eight)
            img = img.transpose(1, 2)
        H, W = img.shape[1:]
        y, x = int(rng.integers(0, H - h + 1)), int(rng.integers(0, W - w + 1))
        out = img[:, y : y + h, x : x + w]
        if rng.random() < 0.5:
            out = out.flip(-1)
        if rng.random() < 0.5:
            out = out.flip(-2)
        return out.float().div(255.0).contiguous()
