"""A torch ``Dataset`` over a PSF dataset directory, reading shards lazily.

Items are (design, field) pairs, the surrogate's training samples (paper Sec. 4.1): the
design's parameters normalized by the mean and standard deviation over the dataset's
designs (stored in the manifest), the field position, the RGB PSF and the RGB relative
illumination.  Shards are memory-mapped when first touched (in each DataLoader worker
separately), and their checksums are verified then, so a damaged shard raises
:class:`DatasetError` naming the file instead of feeding wrong data.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import InputError
from .layout import DatasetError, read_manifest, shard_name, shards_dir
from .verify import open_shard, read_shard_meta


class PsfDataset(Dataset):
    """(design, field) samples of the dataset in ``root``.

    ``psf="psf"`` gives the super-resolved PSFs, ``"psf_sensor"`` the sensor-pitch ones.
    ``designs``: keep only these global design indices (e.g. a held-out split).
    ``verify``: check each shard's CRC-32 checksums when it is first opened.
    ``allow_missing``: use the shards present (else a missing shard is an error).

    Item: dict with ``params`` (P,) float32 normalized, ``field`` () float32 (field angle /
    full field, in [0, 1]), ``psf`` (C, S, S) float32 (unit sum per channel),
    ``vignetting`` (C,) float32 relative illumination, ``design`` int, ``field_deg`` float.
    """

    def __init__(
        self,
        root: "str | Path",
        psf: str = "psf",
        designs: Sequence[int] | None = None,
        verify: bool = True,
        allow_missing: bool = False,
    ):
        self.root = Path(root)
        self.manifest = man = read_manifest(self.root)
        if psf not in ("psf", "psf_sensor"):
            raise InputError(f"psf must be 'psf' or 'psf_sensor', got {psf!r}")
        self.psf_key = psf
        self.verify = verify
        self.fields_deg = np.asarray(man["fields_deg"], float)
        full = float(self.fields_deg.max()) or 1.0
        self.field_norm = (self.fields_deg / full).astype(np.float32)
        self.mean = np.asarray(man["param_mean"], float)
        std = np.asarray(man["param_std"], float)
        self.std = np.where(std > 0, std, 1.0)  # a constant parameter maps to 0
        self.param_names = [p["name"] for p in man["space"]["parameters"]]
        keep = None if designs is None else set(int(i) for i in designs)
        self._shards: list[int] = []
        self._rows: list[np.ndarray] = []  # per shard: rows (positions in the shard) kept
        for k in range(man["n_shards"]):
            d = shards_dir(self.root) / shard_name(k)
            if not d.is_dir():
                if allow_missing:
                    continue
                raise DatasetError(f"{d}: shard missing (finish the dataset, or allow_missing=True)")
            meta = read_shard_meta(self.root, k, man)
            try:
                idx = np.load(d / "design.npy", allow_pickle=False) if meta["n_ok"] else np.zeros(0, np.int64)
            except (OSError, ValueError, EOFError) as exc:
                raise DatasetError(f"{d / 'design.npy'}: unreadable ({exc})") from None
            rows = np.arange(len(idx)) if keep is None else np.flatnonzero([int(i) in keep for i in idx])
            if len(rows):
                self._shards.append(k)
                self._rows.append(rows)
        self._starts = np.cumsum([0] + [len(r) for r in self._rows]).tolist()
        self._open: dict[int, dict] = {}

    @property
    def n_designs(self) -> int:
        return self._starts[-1]

    @property
    def n_fields(self) -> int:
        return len(self.fields_deg)

    def __len__(self) -> int:
        return self.n_designs * self.n_fields

    def normalize(self, params) -> np.ndarray:
        """Raw parameter values (..., P) -> the network's inputs."""
        return (np.asarray(params, float) - self.mean) / self.std

    def _arrays(self, k: int) -> dict:
        if k not in self._open:
            arrays, _ = open_shard(self.root, k, self.manifest, check_hashes=self.verify)
            self._open[k] = arrays
        return self._open[k]

    def __getitem__(self, i: int) -> dict:
        if not 0 <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} samples")
        d, f = divmod(int(i), self.n_fields)
        s = bisect.bisect_right(self._starts, d) - 1
        row = int(self._rows[s][d - self._starts[s]])
        a = self._arrays(self._shards[s])
        return {
            "params": torch.from_numpy(self.normalize(a["params"][row]).astype(np.float32)),
            "field": torch.tensor(self.field_norm[f]),
            "psf": torch.from_numpy(np.array(a[self.psf_key][row, f], dtype=np.float32)),
            "vignetting": torch.from_numpy(np.array(a["relative_illumination"][row, f], dtype=np.float32)),
            "design": int(a["design"][row]),
            "field_deg": float(self.fields_deg[f]),
        }
