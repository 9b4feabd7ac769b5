"""A PSF dataset (``optix dataset``) read whole into memory for the surrogate.

The surrogate trains on random (design, field) pairs; reading them out of memory-mapped
shards one by one is slower than the network on a CPU, so the arrays it needs (parameters,
one PSF kind, relative illumination) are read once, shard by shard, checksums verified.
The sensor-pitch PSFs take 68 KB per design (21 x 21, 13 fields, RGB): 8192 designs are
0.56 GB. The super-resolved ones are 2.5 MB per design at 128 x 128; ``bin`` sums b x b
blocks (a coarser pitch over the same window) to fit more designs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from ..dataset.layout import DatasetError, read_manifest, shard_name, shards_dir
from ..dataset.verify import open_shard
from ..errors import InputError

PSF_KINDS = ("psf_sensor", "psf")


@dataclass
class PsfArrays:
    """Designs in memory: params [N, P] raw values (float64), psf [N, K, C, S, S] float32
    (unit sum per channel), vignetting [N, K, C] float32, design [N] global indices."""

    params: np.ndarray
    psf: np.ndarray
    vignetting: np.ndarray
    design: np.ndarray

    def __len__(self) -> int:
        return len(self.design)

    def subset(self, rows) -> "PsfArrays":
        return PsfArrays(self.params[rows], self.psf[rows], self.vignetting[rows], self.design[rows])


def bin_psf(psf, b: int):
    """Sum b x b pixel blocks of PSFs [..., S, S] (numpy or torch; S divisible by b): the
    same window at b times the pitch, each block's energy kept."""
    if b == 1:
        return psf
    *lead, s, _ = psf.shape
    return psf.reshape(*lead, s // b, b, s // b, b).sum((-3, -1))


def psf_pitch_um(manifest: dict, psf: str, bin: int = 1) -> float:
    s = manifest["settings"]
    return (s["sensor_pixel_um"] if psf == "psf_sensor" else s["pixel_um"]) * bin


def psf_grid(manifest: dict, psf: str, bin: int = 1) -> int:
    """Output window in pixels of the given PSF kind and binning."""
    if psf not in PSF_KINDS:
        raise InputError(f"psf must be one of {PSF_KINDS}, got {psf!r}")
    size = manifest["sensor_size"] if psf == "psf_sensor" else manifest["psf_size"]
    if bin < 1 or size % bin:
        raise InputError(f"bin {bin} does not divide the {size}-pixel {psf} window")
    return size // bin


def _shards(root: Path, man: dict, check: tuple[str, ...]):
    """(k, memory-mapped arrays) of each shard in order, the named arrays' checksums verified;
    a missing shard is an error naming it."""
    for k in range(man["n_shards"]):
        d = shards_dir(root) / shard_name(k)
        if not d.is_dir():
            raise DatasetError(f"{d}: shard missing (finish the dataset with the same `optix dataset` command)")
        yield k, open_shard(root, k, man, check_hashes=check)[0]


def load_arrays(
    root: "str | Path",
    psf: str = "psf_sensor",
    bin: int = 1,
    designs: Sequence[int] | None = None,
    max_designs: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[PsfArrays, dict]:
    """Read the dataset in ``root`` (only ``designs``, global indices, if given; at most
    ``max_designs`` in index order). Missing shards are an error naming the shard."""
    root = Path(root)
    man = read_manifest(root)
    psf_grid(man, psf, bin)
    keep = None if designs is None else np.asarray(sorted(set(int(i) for i in designs)), np.int64)
    parts: dict[str, list] = {"params": [], "psf": [], "vignetting": [], "design": []}
    n = 0
    for k, arrays in _shards(root, man, ("design", "params", psf, "relative_illumination")):
        idx = np.asarray(arrays["design"])
        rows = np.arange(len(idx)) if keep is None else np.flatnonzero(np.isin(idx, keep))
        if max_designs is not None:
            rows = rows[: max_designs - n]
        if len(rows):
            parts["psf"].append(bin_psf(np.asarray(arrays[psf][rows], np.float32), bin))
            parts["params"].append(np.asarray(arrays["params"][rows], np.float64))
            parts["vignetting"].append(np.asarray(arrays["relative_illumination"][rows], np.float32))
            parts["design"].append(idx[rows])
            n += len(rows)
        if progress:
            progress(k + 1, man["n_shards"])
        if (max_designs is not None and n >= max_designs) or (keep is not None and len(idx) and idx[-1] >= keep[-1]):
            break  # shards hold ascending design ranges: the rest have none of the requested designs
    if n == 0:
        raise DatasetError(f"{root}: no designs to read" + ("" if keep is None else " among the requested ones"))
    out = PsfArrays(*(np.concatenate(parts[name]) for name in ("params", "psf", "vignetting", "design")))
    for name in ("params", "psf", "vignetting"):
        if not np.all(np.isfinite(getattr(out, name))):
            raise DatasetError(f"{root}: non-finite values in {name}")
    return out, man


def design_indices(root: "str | Path", max_designs: int | None = None) -> tuple[np.ndarray, dict]:
    """The global indices of the dataset's designs (those the engine traced), ascending; at
    most ``max_designs`` of them, the first in index order (what :func:`load_arrays` reads
    with the same argument). Reads only each shard's index array."""
    root = Path(root)
    man = read_manifest(root)
    parts, n = [], 0
    for _, arrays in _shards(root, man, ("design",)):
        idx = np.asarray(arrays["design"])
        if max_designs is not None:
            idx = idx[: max_designs - n]
        parts.append(idx)
        n += len(idx)
        if max_designs is not None and n >= max_designs:
            break
    if n == 0:
        raise DatasetError(f"{root}: no designs to read")
    return np.concatenate(parts), man


def to_tensors(a: PsfArrays, device="cpu") -> dict[str, torch.Tensor]:
    return {
        "params": torch.as_tensor(a.params, dtype=torch.float32, device=device),
        "psf": torch.as_tensor(a.psf, device=device),
        "vignetting": torch.as_tensor(a.vignetting, device=device),
        "design": torch.as_tensor(a.design, device=device),
    }
