"""A dataset's shards, one at a time: compute shard k's PSFs with the engine
(:func:`compute_shard`), write it atomically (:func:`write_shard`), tell a finished shard
from a damaged one (:func:`shard_complete`) and clear what dead writers left.  Used by
:mod:`.generate` in this process and by :mod:`.cluster` on Dask workers."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..io import fsync_dir, write_json_atomic
from ..lens import Lens
from ..lens.apertures import engine_base
from ..lens_design.constraints import ApertureError, apertures, geometry_problem, own_apertures
from ..lens_design.focus import refocus_many
from ..lens_design.space import ParameterSpace
from .layout import ARRAYS, FORMAT, DatasetError, aligned_empty, save_npy, shard_name, shards_dir
from .manifest import nearest_image_plane
from .settings import DatasetSettings
from .verify import check_shard


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def temporary_name(k: int) -> str:
    """A temporary directory name for shard ``k``: ``.NNNNN.tmp-<pid>@<host>+<token>`` (the
    host, since Dask workers on several machines write into one shared directory; a random
    token, since containers may share a host name and process ids)."""
    return f".{shard_name(k)}.tmp-{os.getpid()}@{socket.gethostname()}+{secrets.token_hex(4)}"


def clean_stale(sdir: Path, k: int) -> None:
    """Remove temporary directories of shard ``k`` left by processes of this host that are
    gone (another host's processes cannot be asked; see :func:`clean_temporaries`)."""
    for p in sdir.glob(f".{shard_name(k)}.tmp-*"):
        pid_s, _, host = p.name.split(".tmp-", 1)[1].partition("@")
        host = host.rsplit("+", 1)[0]
        if host and host != socket.gethostname():
            continue
        try:
            pid = int(pid_s)
        except ValueError:
            pid = -1
        if pid != os.getpid() and not _pid_alive(pid):
            shutil.rmtree(p, ignore_errors=True)


def clean_temporaries(root: Path, shards) -> int:
    """Remove every temporary directory of the given finished shards, whoever left it (a
    worker that died on another host). A process still writing one (a worker wrongly
    declared dead) finds its temporary gone and the shard done: write_shard returns False.
    Returns how many were removed."""
    sdir, n = shards_dir(root), 0
    for k in shards:
        for p in sdir.glob(f".{shard_name(k)}.tmp-*"):
            shutil.rmtree(p, ignore_errors=True)
            n += 1
    return n


def shard_complete(root: Path, k: int, man: dict, log: Callable[[str], None]) -> bool:
    """Shard ``k`` is there and passes verify's checks (metadata, shapes, CRC-32, finite
    values). A damaged one is moved aside (``.NNNNN.damaged-<time>``, kept, never read) to
    be redone."""
    d = shards_dir(root) / shard_name(k)
    if not d.is_dir():
        return False
    try:
        check_shard(root, k, man)
        return True
    except DatasetError as exc:
        aside = d.with_name(f".{d.name}.damaged-{time.time_ns()}")
        try:
            os.rename(d, aside)
        except OSError:
            if d.is_dir():  # not moved, nor by another process
                raise
        log(f"shard {k}: {exc}; moved to {aside.name}, redoing it")
        return False


def focus_points(man: dict) -> tuple[list[float], list[float]]:
    """The fields and wavelengths (nm, equal weights) of a dataset's best focus: by default 7
    of its K fields, spread evenly with both ends, and every channel's wavelengths, with a
    4-ring polar pupil (96 rays per field and wavelength; within 1 um of 8 rings near the
    nominal, against a depth of focus of +-20 um at f/4.4); settings focus_fields, focus_rings."""
    s = DatasetSettings.of_manifest(man["settings"])
    fields = man["fields_deg"]
    k = len(fields)
    nf = min(k, s.focus_fields)
    chosen = [float(fields[i]) for i in np.unique(np.linspace(0, k - 1, nf).round().astype(int))]
    return chosen, sorted({float(wl) for c in man["channels"] for wl, _ in c})


def compute_shard(
    k: int,
    man: dict,
    designs: np.ndarray,
    space: ParameterSpace,
    base: Lens,
    batch: int = 16,
    on_batch: Callable[[int, int], None] | None = None,
    psf_buffer: np.ndarray | None = None,
    sensor_buffer: np.ndarray | None = None,
    checked: bool = False,
) -> tuple[dict, dict]:
    """Arrays and metadata of shard ``k`` (nothing written).  ``psf_buffer``,
    ``sensor_buffer``: float32 arrays of at least shard_size x K x C x S x S (s x s) to hold
    the PSFs and their sensor-pixel versions (saves the page faults of fresh arrays per
    shard).  ``checked``: the designs passed the sampler's checks already (the same rule), so
    the geometry check is not repeated.  The engine computes both versions of each PSF."""
    from .. import engine

    s = DatasetSettings.of_manifest(man["settings"])
    a = k * s.shard_size
    b = min(man["n_designs"], a + s.shard_size)
    fields, channels = man["fields_deg"], [[tuple(p) for p in c] for c in man["channels"]]
    K, C, S = len(fields), len(channels), s.size
    ok_idx, failures = [], []

    def rows(buf, shape):  # rows filled in order, trimmed to m at the end
        if buf is not None and buf.shape[1:] == shape[1:] and len(buf) >= shape[0]:
            return buf[: shape[0]]
        return np.empty(shape, np.float32)

    psf_arr = rows(psf_buffer, (b - a, K, C, S, S))
    sensor_arr = rows(sensor_buffer, (b - a, K, C, s.sensor_size, s.sensor_size))
    ri, image, energy, warnings = [], [], [], {}
    legend: dict[str, int] = {}
    methods: dict[str, list[int]] = {}
    focus_fields, wavelengths = focus_points(man)
    # the geometry check at the clear apertures the dataset's sampler used: each design's own
    # (lens_design.constraints), or the base lens's for the datasets made before that rule
    base_sd = apertures(base) if man.get("sampling_summary", {}).get("apertures", "base-lens") == "base-lens" else None
    traced = engine_base(base, s.apertures)
    # the nearest image plane the focus may choose (focus_within "bfd": the space's min_bfd)
    nearest = nearest_image_plane(man)
    focus_notes: dict[str, list[str]] = {}

    def geometry(d):
        if base_sd is not None:
            return geometry_problem(d, base_sd)
        try:
            return geometry_problem(d, own_apertures(d))
        except ApertureError as err:
            reason, _, message = str(err).partition(": ")
            return (reason, message)

    t0 = time.perf_counter()

    def fail(i, reason):
        failures.append({"design": i, "reason": reason, "params": dict(zip(space.names, map(float, designs[i])))})

    for lo in range(a, b, batch):
        hi = min(b, lo + batch)
        cand = []  # (design index, lens dict) past the geometry check
        for i in range(lo, hi):
            d = space.apply(traced, designs[i])
            bad = None if checked else geometry(d)  # the engine would trace these
            if bad is not None:
                fail(i, f"{bad[0]}: {bad[1]}")
            else:
                cand.append((i, d))
        focus_errors = refocus_many(
            [d for _, d in cand],
            s.focus,
            focus_fields,
            wavelengths,
            primary_nm=base.primary_wavelength_nm,
            rings=s.focus_rings,
            aiming=s.aiming,
        )
        todo, jsons = [], []
        for (i, d), err in zip(cand, focus_errors):
            if err:
                fail(i, f"focus: {err}")
                continue
            image_mm = float(d["surfaces"][-1]["thickness"])
            if nearest is not None and image_mm < nearest:
                # the sensor cannot sit nearer: the image plane at the limit. For "best" that is
                # the best plane allowed (the spot's mean square is a quadratic in the plane's
                # position, so the feasible minimum is the bound nearest the free one)
                where = f"{-image_mm:.4g} mm inside" if image_mm < 0 else f"{image_mm:.4g} mm behind"
                focus_notes[str(i)] = [
                    f"focus: the {s.focus} focus lies {where} the last surface, short of the space's "
                    f"back-focus limit; the image plane is at the limit, {nearest:g} mm"
                ]
                d["surfaces"][-1]["thickness"] = nearest
            if not float(d["surfaces"][-1]["thickness"]) > 0.0:
                fail(
                    i,
                    f"focus: the {s.focus} focus lies {-d['surfaces'][-1]['thickness']:.4g} mm inside the last surface",
                )
                continue
            todo.append((i, float(d["surfaces"][-1]["thickness"])))
            jsons.append(json.dumps(d))
        # the engine writes straight into the shard's rows from row0 on; a failed design's
        # rows are zeros and the later ones move up over them
        row0 = len(ok_idx)
        r = (
            engine.psf_batch(
                jsons,
                fields_deg=fields,
                channels=channels,
                method=s.psf_method,
                pixel_um=s.pixel_um,
                size=S,
                pupil_samples=s.pupil_samples,
                aiming=s.aiming,
                integrate=False,
                fast=True,
                out=psf_arr[row0 : row0 + len(jsons)],
                sensor=(s.sensor_pixel_um, s.sensor_size),
                sensor_out=sensor_arr[row0 : row0 + len(jsons)],
                accuracy=s.accuracy,
            )
            if jsons
            else {"ok": []}
        )
        n_wl = sum(len(c) for c in channels)
        for j, (i, image_mm) in enumerate(todo):
            if r["ok"][j]:
                if len(ok_idx) != row0 + j:
                    psf_arr[len(ok_idx)] = psf_arr[row0 + j]
                    sensor_arr[len(ok_idx)] = sensor_arr[row0 + j]
                ok_idx.append(i)
                ri.append(r["relative_illumination"][j])
                energy.append(r["energy_in_window"][j])
                image.append(image_mm)
                said = focus_notes.get(str(i), []) + list(r["warnings"][j] or [])
                if said:
                    warnings[str(i)] = said
                # method and sampling of each PSF (fields x wavelengths), as codes into a legend
                per = r["methods"][j * K * n_wl : (j + 1) * K * n_wl]
                methods[str(i)] = [legend.setdefault(m, len(legend)) for m in per]
            else:
                fail(i, r["errors"][j] or "engine error")
        failures.sort(key=lambda f: f["design"])
        if on_batch:
            on_batch(hi - lo, sum(1 for f in failures if lo <= f["design"] < hi))
    m = len(ok_idx)
    arrays = {
        "design": np.array(ok_idx, np.int64),
        "params": designs[ok_idx].astype(np.float64).reshape(m, designs.shape[1]),
        "psf": psf_arr[:m],
        "psf_sensor": sensor_arr[:m],
        "relative_illumination": (np.stack(ri).astype(np.float64) if m else np.zeros((0, K, C))),
        "image_distance": np.array(image, np.float64),
        "energy_in_window": (np.stack(energy).astype(np.float32) if m else np.zeros((0, K, C), np.float32)),
    }
    meta = {
        "format": FORMAT,
        "shard": k,
        "designs": [a, b],
        "n_ok": m,
        "n_failed": len(failures),
        "failures": failures,
        "warnings": warnings,
        "seconds": time.perf_counter() - t0,
        "psf_methods": {"legend": list(legend), "order": "fields x wavelengths (channels flattened)", "codes": methods},
    }
    return arrays, meta


def shard_buffers(man: dict) -> tuple[np.ndarray, np.ndarray]:
    """Aligned float32 arrays for one shard's PSFs and sensor-pitch PSFs (compute_shard's
    ``psf_buffer`` and ``sensor_buffer``), reused from shard to shard by their owner."""
    lead = (man["settings"]["shard_size"], len(man["fields_deg"]), len(man["channels"]))
    return (
        aligned_empty(lead + (man["psf_size"],) * 2, np.float32),
        aligned_empty(lead + (man["sensor_size"],) * 2, np.float32),
    )


def write_shard(root: Path, k: int, arrays: dict, meta: dict) -> bool:
    """Write shard ``k`` atomically; False if another process finished it first."""
    sdir = shards_dir(root)
    sdir.mkdir(parents=True, exist_ok=True)
    final = sdir / shard_name(k)
    tmp = sdir / temporary_name(k)
    try:
        tmp.mkdir()
        files = {}
        for name in ARRAYS:
            p = tmp / f"{name}.npy"
            crc = save_npy(p, arrays[name])
            files[name] = {"crc32": crc, "shape": list(arrays[name].shape), "dtype": str(arrays[name].dtype)}
        write_json_atomic(tmp / "shard.json", {**meta, "files": files})
        fsync_dir(tmp)
        os.rename(tmp, final)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if final.is_dir():  # done meanwhile by another process on the same range
            return False
        raise
    fsync_dir(sdir)
    return True
