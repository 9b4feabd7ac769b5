"""Combine dataset directories produced by processes that ran disjoint shard ranges."""

from __future__ import annotations

import filecmp
import os
import shutil
from pathlib import Path
from typing import Sequence

from ..errors import InputError
from ..io import claim_out_dir, write_json_atomic
from .layout import DatasetError, differing_keys, read_manifest, shard_name, shards_dir
from .shards import temporary_name
from .verify import read_shard_meta

# manifest keys that may differ between processes of one dataset
_LOCAL = {"created_unix", "versions"}


def merge(out: "str | Path", parts: Sequence["str | Path"]) -> dict:
    """Copy every complete shard of ``parts`` into ``out`` (created from the first part's
    manifest and designs).  The parts must be the same dataset (same manifest apart from
    when and where it was made); a shard present in several parts must be identical."""
    out = Path(out)
    parts = [Path(p) for p in parts]
    if not parts:
        raise InputError("merge: no input directories")
    mans = [read_manifest(p) for p in parts]
    ref = {k: v for k, v in mans[0].items() if k not in _LOCAL}
    for p, m in zip(parts[1:], mans[1:]):
        diff = differing_keys(ref, m, (set(ref) | set(m)) - _LOCAL)
        if diff:
            raise DatasetError(
                f"{p / 'manifest.json'}: a different dataset from {parts[0]} (differs in: {', '.join(diff)})"
            )
    # a dataset of its own (resumed), or a folder of nothing but what merge writes: never over
    # another command's files (optix sample's designs.csv, a design run)
    claim_out_dir(
        out, "dataset", {"designs.csv", "shards"}, marker="manifest.json", own=lambda d: _same_designs(d, parts[0])
    )
    out.mkdir(parents=True, exist_ok=True)
    if (out / "manifest.json").exists():
        m = read_manifest(out)
        diff = differing_keys(ref, m, ref)
        if diff:
            raise DatasetError(f"{out / 'manifest.json'}: a different dataset (differs in: {', '.join(diff)})")
    else:
        tmp_csv = out / f".designs.csv.tmp{os.getpid()}"
        shutil.copyfile(parts[0] / "designs.csv", tmp_csv)
        os.replace(tmp_csv, out / "designs.csv")
        write_json_atomic(out / "manifest.json", mans[0])
    copied, present = [], []
    sdir = shards_dir(out)
    sdir.mkdir(exist_ok=True)
    for k in range(ref["n_shards"]):
        dst = sdir / shard_name(k)
        srcs = [shards_dir(p) / shard_name(k) for p in parts if (shards_dir(p) / shard_name(k)).is_dir()]
        if not srcs:
            continue
        metas = [read_shard_meta(s.parent.parent, k, ref)["files"] for s in srcs]
        if any(m != metas[0] for m in metas[1:]):
            raise DatasetError(f"shard {k} differs between {', '.join(str(s) for s in srcs)}")
        if dst.is_dir():
            present.append(k)
            continue
        if srcs[0].resolve() == dst.resolve():
            continue
        tmp = sdir / temporary_name(k)  # unique: nobody else's to clear
        shutil.copytree(srcs[0], tmp)
        os.rename(tmp, dst)
        copied.append(k)
    return {"out": str(out), "copied": copied, "already_present": present}


def _same_designs(folder: Path, part: Path) -> bool:
    """A designs.csv in ``folder`` without a manifest is merge's own (a merge stopped between its
    two writes) only where it is the dataset's: byte for byte the first part's."""
    mine = folder / "designs.csv"
    return not mine.exists() or filecmp.cmp(mine, part / "designs.csv", shallow=False)
