"""The manifest and the design list of a dataset directory: created once from the seed,
checked against the request on every later run (docs/dataset.md)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError
from ..io import claim_out_dir, write_json_atomic
from ..lens import Lens
from ..lens.apertures import engine_base
from ..lens_design.constraints import Limits
from ..lens_design.sampling import read_designs_csv, sample_designs, write_designs_csv
from ..lens_design.space import Parameter, ParameterSpace, SpaceError
from .layout import FORMAT, DatasetError, differing_keys, read_json, sha256_file
from .settings import BEFORE_KEY, DatasetSettings, field_positions


def _request(
    space: ParameterSpace, base: Lens, n: int, seed: int, s: DatasetSettings, fields: list[float], channels
) -> dict:
    """The part of the manifest that defines the data (must match on resume)."""
    return {
        "format": FORMAT,
        "n_designs": n,
        "seed": seed,
        # the best-focus sampling and its limit only where not the default (manifests before them have none)
        "settings": {
            k: v
            for k, v in asdict(s).items()
            if not (k in ("focus_fields", "focus_rings") and v == getattr(DatasetSettings, k))
            and not (k in BEFORE_KEY and v == BEFORE_KEY[k])
        },
        "fields_deg": fields,
        "channels": [[list(p) for p in c] for c in channels],
        "channel_names": ["R", "G", "B"] if len(channels) == 3 else [f"C{i}" for i in range(len(channels))],
        "psf_size": s.size,
        "sensor_size": s.sensor_size,
        "n_shards": math.ceil(n / s.shard_size),
        "space": {
            "source": space.source,
            "lens": space.lens_ref,
            "constraints": space.constraints,
            "parameters": space.to_json(),
        },
        "base_lens": base.data,
    }


def resolve_fields_and_channels(
    base: Lens, s: DatasetSettings, log: Callable[[str], None] = lambda m: None
) -> tuple[list[float], list, dict]:
    """The K field positions and the channels' (wavelength, weight) lists.  ``n_fields`` 0
    and ``channels`` "auto" are chosen for ``s.accuracy`` on the base design (optix_e2e.accuracy.auto;
    deterministic, so a resumed run recomputes and checks them); the choice and its
    estimated errors are returned for the manifest's ``auto`` entry."""
    from ..accuracy import auto as _auto

    info: dict = {}
    js = [json.dumps(engine_base(base, s.apertures))]
    if s.channels == "auto":
        ch = _auto.choose_wavelengths(js, base.max_field_deg, s.accuracy, size=s.size, pixel_um=s.pixel_um)
        channels = [c["wavelengths"] for c in ch.values()]
        info["channels"] = {k: {"k": v["k"], "estimated_rel_l1": v["estimated_rel_l1"]} for k, v in ch.items()}
    else:
        channels = base.rgb_channels(s.channels)
    k = s.n_fields
    if k == 0:
        fk = _auto.choose_fields(
            js, base.max_field_deg, base.primary_wavelength_nm, s.accuracy, size=s.size, pixel_um=s.pixel_um
        )
        k = fk["K"]
        info["fields"] = fk
        if not fk["met"]:
            log(
                f"fields auto: no K up to {max(_auto.K_FIELDS)} interpolates within {s.accuracy:.1%} "
                f"(K={max(_auto.K_FIELDS)}: {fk['mean_rel_l1'][str(max(_auto.K_FIELDS))]:.1%}); using {k} fields"
            )
    if info:
        info["target_rel_l1"] = s.accuracy
    return field_positions(base, k), channels, info


def _versions() -> dict:
    import importlib.metadata as md
    import platform

    out = {"python": platform.python_version(), "numpy": np.__version__}
    for pkg in ("optix-e2e", "scipy"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = None
    return out


def prepare(
    out: Path,
    space: ParameterSpace,
    base: Lens,
    n: int,
    seed: int,
    s: DatasetSettings,
    log: Callable[[str], None] = lambda m: None,
) -> tuple[dict, np.ndarray]:
    """Create or check ``out``'s manifest and designs; returns (manifest, designs (n, P))."""
    fields, channels, auto = resolve_fields_and_channels(base, s, log)
    req = _request(space, base, n, seed, s, fields, channels)
    if auto:
        req["auto"] = auto
    mpath = out / "manifest.json"
    if mpath.exists():
        man = read_json(mpath, "manifest")
        if not isinstance(man, dict):
            raise DatasetError(f"{mpath}: not a dataset manifest (a JSON object); use another --out")
        diff = differing_keys(man, req, req)
        if diff:
            detail = ", ".join(diff)
            held, asked = man.get("settings"), req["settings"]
            at = DatasetSettings.recorded
            keys = (
                sorted(k for k in set(held) | set(asked) if at(held, k) != at(asked, k))
                if isinstance(held, dict)
                else []
            )
            if "settings" in diff and keys:  # which ones, as made and as asked
                detail += " (" + ", ".join(f"{k}: {at(held, k)!r} there, {at(asked, k)!r} asked" for k in keys) + ")"
            raise DatasetError(
                f"{mpath}: this directory holds a different dataset (differs in: "
                f"{detail}); use another --out or the same arguments"
            )
        dpath = out / "designs.csv"
        want = man.get("designs_csv_sha256")
        if not dpath.exists() or (want is not None and sha256_file(dpath) != want):
            raise DatasetError(f"{dpath}: missing or changed since the manifest was written")
        try:
            designs = read_designs_csv(dpath, space.names)
        except (SpaceError, ValueError) as exc:
            raise DatasetError(f"{dpath}: unreadable ({exc})") from None
        if want is None:  # an older manifest: the designs must be the ones the seed gives
            log(f"{mpath}: no designs_csv_sha256; checking designs.csv against the designs of seed {seed}")
            limits = Limits.from_dict(space.constraints, f"{space.source}: [constraints]")
            rule = man.get("sampling_summary", {}).get("apertures", "base-lens")  # absent: made before the rule
            again = sample_designs(space, base, n, seed=seed, method=s.sampling, limits=limits, apertures=rule).values
            if designs.shape != again.shape or not np.array_equal(designs, again):
                raise DatasetError(
                    f"{dpath}: not the designs of seed {seed} (and the manifest has no "
                    f"designs_csv_sha256 to check it by)"
                )
        return man, designs
    # a new dataset: only into an empty folder or one a start that stopped early left
    claim_out_dir(out, "dataset", {"designs.csv", "shards"}, marker="manifest.json")
    log(f"sampling {n} designs ({s.sampling}, seed {seed})")
    limits = Limits.from_dict(space.constraints, f"{space.source}: [constraints]")
    res = sample_designs(space, base, n, seed=seed, method=s.sampling, limits=limits, apertures=s.apertures)
    out.mkdir(parents=True, exist_ok=True)
    write_designs_csv(out / "designs.csv", space.names, res.values)
    man = {
        **req,
        "sampling_summary": res.summary(),
        # the paper normalizes parameters by their mean and standard deviation over the designs
        "param_mean": res.values.mean(axis=0).tolist(),
        "param_std": res.values.std(axis=0).tolist(),
        "designs_csv_sha256": sha256_file(out / "designs.csv"),
        "versions": _versions(),
        "created_unix": time.time(),
    }
    write_json_atomic(mpath, man)
    return man, res.values


def space_and_base(manifest: dict) -> tuple[ParameterSpace, Lens]:
    """The parameter space and base lens a manifest records (no files needed); a manifest
    without them (a damaged or hand-made checkpoint's) is one ValueError naming the key."""
    sp = manifest.get("space") if isinstance(manifest, dict) else None
    if (
        not isinstance(sp, dict)
        or not isinstance(sp.get("parameters"), list)
        or not all(isinstance(p, dict) for p in sp["parameters"])
    ):
        raise InputError(
            "the manifest has no parameter space ('space' with a list of 'parameters'); "
            "it is damaged or not a dataset's"
        )
    if not isinstance(manifest.get("base_lens"), dict):
        raise InputError("the manifest has no base lens ('base_lens'); it is damaged or not a dataset's")
    try:
        space = ParameterSpace([Parameter(**p) for p in sp["parameters"]], source=str(sp.get("source", "<manifest>")))
    except TypeError as err:
        raise InputError(f"the manifest's parameter space is damaged ({err})") from None
    return space, Lens(manifest["base_lens"], source="<manifest base lens>")


def back_focus_limit(manifest: dict) -> float | None:
    """The space's back-focus limit (its [constraints] min_bfd, mm), None where it has none."""
    limit = (manifest.get("space", {}).get("constraints") or {}).get("min_bfd")
    return None if limit is None else float(limit)


def nearest_image_plane(manifest: dict) -> float | None:
    """The nearest distance behind the last surface where the dataset's focus may put the
    image plane (mm): the space's back-focus limit, where it is above 0, under ``focus_within
    = "bfd"`` (a focus "best" or "paraxial"), else None (no limit)."""
    s = DatasetSettings.of_manifest(manifest["settings"])
    limit = back_focus_limit(manifest)
    return limit if limit is not None and limit > 0 and s.focus_within == "bfd" and s.focus != "fixed" else None


def refocused_designs(manifest: dict, values, image_distance) -> list[dict]:
    """Lens dicts of designs as the dataset traced them: parameter values [N, P] written into
    the base lens with the manifest's apertures, image plane at the recorded distances [N]."""
    space, base = space_and_base(manifest)
    traced = engine_base(base, manifest["settings"]["apertures"])
    out = []
    for v, z in zip(np.atleast_2d(values), np.atleast_1d(image_distance)):
        d = space.apply(traced, v)  # its own surface dicts: setting the distance changes only d
        d["surfaces"][-1]["thickness"] = float(z)
        out.append(d)
    return out
