"""Check a dataset directory against its manifest and digest its contents."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import Collection

import numpy as np

from ..lens_design.sampling import read_designs_csv
from ..lens_design.space import SpaceError
from .layout import (
    FORMAT,
    VALUES,
    DatasetError,
    crc32_file,
    read_json,
    read_manifest,
    sha256_file,
    shard_name,
    shards_dir,
)


def expected_shapes(man: dict, m: int) -> dict:
    K, C = len(man["fields_deg"]), len(man["channels"])
    S, s = man["psf_size"], man["sensor_size"]
    P = len(man["space"]["parameters"])
    return {
        "design": ((m,), "int64"),
        "params": ((m, P), "float64"),
        "psf": ((m, K, C, S, S), "float32"),
        "psf_sensor": ((m, K, C, s, s), "float32"),
        "relative_illumination": ((m, K, C), "float64"),
        "image_distance": ((m,), "float64"),
        "energy_in_window": ((m, K, C), "float32"),
    }


def read_shard_meta(root: Path, k: int, man: dict) -> dict:
    """Shard ``k``'s shard.json, checked: this shard of this format, its design range, and
    counts, failures and file entries of the right types.  Raises :class:`DatasetError`."""
    path = shards_dir(root) / shard_name(k) / "shard.json"
    meta = read_json(path, f"shard {k} metadata")
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("shard") != k:
        raise DatasetError(f"{path}: not shard {k} of a {FORMAT} dataset")
    size = man["settings"]["shard_size"]
    a, b = k * size, min(man["n_designs"], (k + 1) * size)
    if meta.get("designs") != [a, b]:
        raise DatasetError(f"{path}: covers designs {meta.get('designs')}, expected [{a}, {b}]")
    m, n_failed, failures = meta.get("n_ok"), meta.get("n_failed"), meta.get("failures")
    if not (
        isinstance(m, int)
        and isinstance(n_failed, int)
        and isinstance(failures, list)
        and all(isinstance(f, dict) and isinstance(f.get("design"), int) for f in failures)
        and isinstance(meta.get("files"), dict)
    ):
        raise DatasetError(f"{path}: damaged (n_ok, n_failed, failures or files missing or malformed)")
    if m < 0 or n_failed < 0 or m + n_failed != b - a or len(failures) != n_failed:
        raise DatasetError(f"{path}: {m} ok + {n_failed} failed designs != {b - a}")
    return meta


def open_shard(root: Path, k: int, man: dict, check_hashes: "bool | Collection[str]" = True) -> tuple[dict, dict]:
    """Memory-mapped arrays and metadata of shard ``k``, checked against the manifest
    (shapes, dtypes, design ranges, and with ``check_hashes`` the CRC-32 of every file, or
    of the named arrays only: a reader of some arrays need not read the others' bytes).
    Raises :class:`DatasetError` naming the file and the problem."""
    d = shards_dir(root) / shard_name(k)
    meta = read_shard_meta(root, k, man)
    size = man["settings"]["shard_size"]
    a, b = k * size, min(man["n_designs"], (k + 1) * size)
    m = meta["n_ok"]
    arrays = {}
    for name, (shape, dtype) in expected_shapes(man, m).items():
        p = d / f"{name}.npy"
        info = meta["files"].get(name)
        if not isinstance(info, dict) or not isinstance(info.get("crc32"), str):
            raise DatasetError(f"{d / 'shard.json'}: no checksum for {name}.npy")
        if not p.is_file():
            raise DatasetError(f"{p}: missing")
        check = check_hashes if isinstance(check_hashes, bool) else name in check_hashes
        if check and crc32_file(p) != info["crc32"]:
            raise DatasetError(f"{p}: checksum mismatch (the file was changed or damaged after it was written)")
        try:
            arr = np.load(p, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise DatasetError(f"{p}: unreadable array ({exc})") from None
        if arr.shape != shape or str(arr.dtype) != dtype:
            raise DatasetError(f"{p}: shape {arr.shape} {arr.dtype}, expected {shape} {dtype}")
        arrays[name] = arr
    idx = np.asarray(arrays["design"])
    failed = {f["design"] for f in meta["failures"]}
    if np.any(np.diff(idx) <= 0) or (m and (idx[0] < a or idx[-1] >= b)) or failed & set(idx.tolist()):
        raise DatasetError(
            f"{d / 'design.npy'}: design indices not ascending inside [{a}, {b}) or overlapping the failures"
        )
    return arrays, meta


# The ranges the engine guarantees for a design it reports ok (crates/psf-engine:
# psf::ENERGY_EXCESS_TOL; relative illumination >= 0 with no upper bound, since a lens whose
# image of the field does not fold may exceed 1 at the corner and one that folds is refused,
# spot::field_fold); a stored value outside them is a damaged shard or one written before the
# engine refused such designs.
RANGES = {"relative_illumination": (0.0, math.inf), "energy_in_window": (0.0, 1.01)}
# Each PSF channel sums to 1 (float32 sums of up to 128 x 128 values).
SUM_TOL = 1e-3


def _out_of_range(path: Path, what: str, bad: np.ndarray, values: np.ndarray, design: np.ndarray) -> DatasetError:
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    return DatasetError(
        f"{path}: {int(bad.sum())} {what} (first: design {int(design[first[0]])}, index {first[1:]}, "
        f"value {float(values[first]):.6g})"
    )


def check_shard(root: Path, k: int, man: dict, check_hashes: bool = True) -> tuple[dict, dict]:
    """:func:`open_shard` and the values' checks (all finite, relative illumination and window
    energy in range, PSFs non-negative with unit-sum channels, sensor PSFs summing to at most
    1 and more than 0): what verify checks per shard and what a resumed generation checks before it skips a
    shard."""
    arrays, meta = open_shard(root, k, man, check_hashes)
    d = shards_dir(root) / shard_name(k)
    for name in VALUES:
        if not np.all(np.isfinite(arrays[name])):
            raise DatasetError(f"{d / (name + '.npy')}: non-finite values")
    design = np.asarray(arrays["design"])
    for name, (lo, hi) in RANGES.items():
        v = np.asarray(arrays[name])
        bad = (v < lo) | (v > hi)
        if bad.any():
            raise _out_of_range(d / f"{name}.npy", f"values outside [{lo}, {hi}]", bad, v, design)
    for name, exact in (("psf", True), ("psf_sensor", False)):
        a = arrays[name]
        if len(a) == 0:
            continue
        sums = np.stack([np.asarray(a[i], dtype=np.float64).sum(axis=(-1, -2)) for i in range(len(a))])
        low = np.stack([np.asarray(a[i]).min(axis=(-1, -2)) for i in range(len(a))])
        if (low < 0).any():
            raise _out_of_range(d / f"{name}.npy", "channels with negative values", low < 0, low, design)
        # a sensor PSF holds the light of its window: at most 1, and never none (the fine PSF of
        # the same channel has unit sum; an all-zero copy is a damaged or forged shard)
        bad = np.abs(sums - 1) > SUM_TOL if exact else (sums > 1 + SUM_TOL) | (sums <= 0)
        if bad.any():
            raise _out_of_range(
                d / f"{name}.npy",
                "channels whose sum is not 1" if exact else "channels summing above 1 or to nothing",
                bad,
                sums,
                design,
            )
    return arrays, meta


def _designs_csv(root: Path, man: dict, problems: list, notes: list) -> "np.ndarray | None":
    """designs.csv checked against the manifest's sha256 (a manifest without one gets a note)
    and its design count; its values (n, P) for comparing with the shards, or None."""
    path = root / "designs.csv"
    if not path.is_file():
        problems.append(f"{path}: missing")
        return None
    want = man.get("designs_csv_sha256")
    if want is None:
        notes.append(
            f"{root / 'manifest.json'}: no designs_csv_sha256 (an older manifest): designs.csv is "
            f"checked against the shards' parameters only"
        )
    elif sha256_file(path) != want:
        problems.append(
            f"{path}: changed since the manifest was written (its sha256 differs from the "
            f"manifest's designs_csv_sha256)"
        )
    try:
        designs = read_designs_csv(path, [q["name"] for q in man["space"]["parameters"]])
    except (SpaceError, ValueError, UnicodeDecodeError) as exc:
        problems.append(f"{path}: unreadable ({exc})")
        return None
    if len(designs) != man["n_designs"]:
        problems.append(f"{path}: {len(designs)} designs, the manifest says {man['n_designs']}")
        return None
    return designs


def verify(root: "str | Path", check_hashes: bool = True) -> dict:
    """Check every shard; returns a JSON-able report.  ``digest`` is a sha256 over the
    contents in canonical order (per design by index: index, parameters, PSFs, sensor PSFs,
    relative illumination, image distance, energy in the window; then the failed indices),
    independent of the shard layout.  ``n_with_warnings`` counts designs whose PSFs carry
    an engine warning (shard.json lists them), ``min_energy_in_window`` is the smallest
    fraction of a PSF's energy inside the window, ``psf_methods`` how many PSFs each method
    and sampling computed (what method auto chose, from each shard's meta.json)."""
    root = Path(root)
    man = read_manifest(root)
    problems, missing, notes = [], [], []
    designs = _designs_csv(root, man, problems, notes)
    n_ok = n_failed = n_warn = 0
    min_energy = 1.0
    failed_idx = []
    methods: dict[str, int] = {}
    h = hashlib.sha256()
    for k in range(man["n_shards"]):
        if not (shards_dir(root) / shard_name(k)).is_dir():
            missing.append(k)
            continue
        try:
            arrays, meta = check_shard(root, k, man, check_hashes)
        except DatasetError as exc:
            problems.append(str(exc))
            continue
        idx = np.asarray(arrays["design"])
        if designs is not None and len(idx):
            differ = idx[np.any(np.asarray(arrays["params"]) != designs[idx], axis=1)]
            if len(differ):
                problems.append(
                    f"{shards_dir(root) / shard_name(k) / 'params.npy'}: the parameters of design "
                    f"{differ[0]} ({len(differ)} in all) differ from designs.csv"
                )
        for j, i in enumerate(idx):
            h.update(np.int64(i).tobytes())
            for name in VALUES:
                h.update(np.ascontiguousarray(arrays[name][j]).astype(arrays[name].dtype.newbyteorder("<")).tobytes())
        n_ok += meta["n_ok"]
        n_failed += meta["n_failed"]
        n_warn += len(meta.get("warnings", {}))
        if meta["n_ok"]:
            min_energy = min(min_energy, float(np.min(arrays["energy_in_window"])))
        failed_idx += [f["design"] for f in meta["failures"]]
        pm = meta.get("psf_methods")
        if pm:
            for codes in pm["codes"].values():
                for c in codes:
                    methods[pm["legend"][c]] = methods.get(pm["legend"][c], 0) + 1
    for i in sorted(failed_idx):
        h.update(b"failed" + np.int64(i).tobytes())
    return {
        "ok": not problems and not missing,
        "notes": notes,
        "n_designs": n_ok,
        "n_failed": n_failed,
        "n_with_warnings": n_warn,
        "min_energy_in_window": min_energy,
        "n_shards": man["n_shards"],
        "missing_shards": missing,
        "problems": problems,
        "psf_methods": dict(sorted(methods.items())),
        "digest": h.hexdigest(),
    }
