"""A seeded probe of whole commands with damaged inputs.

Each scenario builds, from a seeded generator, an input a careless or hostile user might
give one command: a design config with a setting out of reason, a COCO set with one kind of
damage, a crafted detector checkpoint, a broken image, a lens file with a flipped value, an
``--out`` folder that holds another kind of run, a Dask address that leads nowhere. The
command runs in-process under a time bound (a hang fails the probe). Every probe asserts
what the issue asks of every command:

* the exit status (1 for a failed run, 2 for a usage error; 0 where the input is only odd);
* one ``Error:`` line, naming the culprit (the file, the key, the option), and no traceback;
* no NaN or infinity in any file the command wrote (JSON, CSV, text, .npy);
* every file that existed before, byte-identical (inputs, other runs, unrelated files).

tests/cli/test_probe.py probes every numeric option; tests/cli/test_bad_input.py holds targeted
cases (diverging training, damaged states).  ``OPTIX_PROBE_SEEDS=N`` runs more seeds.
"""

from __future__ import annotations

import json
import math
import os
import random
import re
import signal
import struct
import zlib
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from optix_e2e.cli import main

SEEDS = range(int(os.environ.get("OPTIX_PROBE_SEEDS", "3")))
TIME_BOUND_S = 120
HOSTILE = [float("nan"), float("inf"), -1e300, 1e300, "abc", [1, 2], {"a": 1}, True, -1]
REPO = Path(__file__).resolve().parents[2]


# ----------------------------------------------------------------------------------- checks
class Hang(Exception):
    pass


@contextmanager
def time_bound(seconds: int):
    def alarm(signum, frame):
        raise Hang(f"no answer in {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def snapshot(root: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in root.rglob("*") if p.is_file() and not p.is_symlink()}


def non_finite_in(path: Path) -> bool:
    """Whether a written data file holds NaN or infinity as a number: a JSON value, a CSV
    cell, an .npy element (an error message quoting a file's 'inf' is text, not a number)."""
    if path.suffix == ".npy":
        a = np.load(path, allow_pickle=False)
        return a.dtype.kind == "f" and not np.isfinite(a).all()
    if path.suffix == ".json":

        def bad(v) -> bool:
            if isinstance(v, float):
                return not math.isfinite(v)
            if isinstance(v, dict):
                return any(bad(x) for x in v.values())
            if isinstance(v, list):
                return any(bad(x) for x in v)
            return False

        return bad(json.loads(path.read_text(encoding="utf-8")))
    if path.suffix == ".csv":
        import csv

        with open(path, newline="", encoding="utf-8") as f:
            for row in csv.reader(f):
                for cell in row:
                    try:
                        if not math.isfinite(float(cell)):
                            return True
                    except ValueError:
                        continue
    return False


def invoke(args: list[str]):
    with time_bound(TIME_BOUND_S):
        return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=True)


def check(tmp_path: Path, args: list, code: int, culprit: str, nothing_new: bool = False):
    """Run ``args`` and assert the probe's four properties; ``culprit`` is a regex the one
    error line must match (ignored for exit 0)."""
    before = snapshot(tmp_path)
    res = invoke(args)
    shown = f"\n$ optix {' '.join(map(str, args))}\n{res.output[-3000:]}\n{res.exception!r}"
    assert "Traceback" not in res.output, shown
    assert res.exception is None or isinstance(res.exception, SystemExit), shown
    assert res.exit_code == code, shown
    if code:
        errors = [ln for ln in res.output.splitlines() if ln.startswith("Error:")]
        assert len(errors) == 1 and re.search(culprit, errors[0]), shown
    after = snapshot(tmp_path)
    for p, data in before.items():
        assert after.get(p) == data, f"{p} changed or vanished{shown}"
    new = [p for p in after if p not in before]
    assert not [p for p in new if non_finite_in(p)], f"NaN/inf written in {new}{shown}"
    if nothing_new:
        assert not new, f"wrote {new}{shown}"
    return res


def keep_file(tmp_path: Path) -> None:
    (tmp_path / "keep.txt").write_bytes(b"a file no command may touch\n")


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def street(tmp_path_factory) -> Path:
    from optix_e2e.scenes.coco import write_street_coco

    folder = tmp_path_factory.mktemp("probe") / "street"
    write_street_coco(folder, 3, (48, 64), seed=1)
    return folder


@pytest.fixture(scope="module")
def detector_run(tmp_path_factory, street) -> Path:
    from optix_e2e.tasks.detector_train import train_detector

    run = tmp_path_factory.mktemp("probe") / "detector"
    train_detector(street, run, steps=1, batch=1, progress=False, log=lambda m: None)
    return run


def copy_tree(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


# ---------------------------------------------------------------------- optix design
def _design_config(rng: random.Random) -> tuple[str, str]:
    from optix_e2e.camera_design.config import RANGES

    kind = rng.choice(["value", "unknown", "syntax", "binary", "nested"])
    if kind == "value":
        key, value = rng.choice(sorted(RANGES)), rng.choice(HOSTILE)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            lo, hi, _ = RANGES[key]
            if math.isfinite(value) and lo <= value <= hi:
                value = float("nan")
        return f"{key} = {_toml(value)}\n", key
    if kind == "unknown":
        return "bacth = 4\n", "bacth"
    if kind == "syntax":
        return "batch = = 3\n", r"config|toml|line"
    if kind == "binary":
        return "\x00\xff\xfe garbage \x01\n", r"config|toml|line|UTF|decode"
    return "a = " + "[" * 5000 + "]" * 5000 + "\n", r"nested|deep|config"


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


@pytest.mark.parametrize("seed", SEEDS)
def test_design_with_a_damaged_config_is_one_error_and_claims_no_folder(tmp_path, seed):
    rng = random.Random(seed)
    text, culprit = _design_config(rng)
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(text, encoding="utf-8", errors="surrogateescape")
    keep_file(tmp_path)
    check(
        tmp_path,
        ["design", "iq-software", "--config", cfg, "--out", tmp_path / "out", "--budget", "smoke", "--quiet"],
        1,
        rf"cfg\.toml.*({culprit})|({culprit}).*cfg\.toml",
        nothing_new=True,
    )


OTHER_RUNS = {
    "detector run": {"detector.pt": b"\x80\x02}q\x00.", "history.csv": b"step,loss\n1,0.5\n"},
    "street scenes": {"annotations.json": b'{"images": [], "annotations": [], "categories": []}\n'},
    "surrogate run": {"train.json": b'{"steps": 5}\n', "tb/events": b"\x00\x01"},
    "lens survey": {"survey.json": b"{}\n", "survey.csv": b"file,target\n"},
    "unrelated files": {"notes.md": b"# my notes\n", "photo.png": b"\x89PNG\r\n\x1a\n"},
}


@pytest.mark.parametrize("seed", SEEDS)
def test_a_run_into_a_folder_of_another_kind_is_refused_and_leaves_it_as_it_was(tmp_path, seed):
    rng = random.Random(seed)
    kind = rng.choice(sorted(OTHER_RUNS))
    out = tmp_path / "other"
    for name, data in OTHER_RUNS[kind].items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    command = rng.choice(["design", "scenes", "detect", "survey"])
    if command == "design":
        args = ["design", "iq-software", "--out", out, "--budget", "smoke", "--quiet"]
    elif command == "scenes":
        args = ["scenes", "street", "--out", out, "-n", "1", "--size", "32x48"]
    elif command == "detect":
        from optix_e2e.scenes.coco import write_street_coco

        write_street_coco(tmp_path / "data", 1, (48, 64), seed=0)
        args = ["detect", "train", tmp_path / "data", "--out", out, "--steps", "1", "--batch", "1", "--quiet"]
    else:
        (tmp_path / "lenses").mkdir()
        args = ["lens", "survey", tmp_path / "lenses", "--out", out]
    if command == "survey" and kind == "lens survey":
        # a survey's own folder: it may write its files again (whole files, atomically)
        res = invoke(args)
        assert res.exit_code == 0 and "Traceback" not in res.output, res.output
        return
    check(tmp_path, args, 1, r"other|--out|holds|not empty")


# --------------------------------------------------------------- optix detect train / eval
COCO_DAMAGE = [
    (
        lambda d, r: d["annotations"][0].__setitem__("category_id", r.choice([-1, 0, 7, 10**12])),
        r"annotations\.json|category",
    ),
    (
        lambda d, r: d["annotations"][0].__setitem__(
            "bbox", r.choice([[0, 0, -5, 3], [1, 2, 3], ["a", 0, 1, 1], [float("nan"), 0, 1, 1]])
        ),
        r"annotations\.json|bbox",
    ),
    (
        lambda d, r: d["images"][0].__setitem__(
            "file_name", r.choice(["../../etc/hostname", "/etc/hostname", "a/../../x.png", "missing.png"])
        ),
        r"annotations\.json|images|file",
    ),
    (
        lambda d, r: d["annotations"][0].__setitem__("illumination", r.choice([float("nan"), float("inf"), -2])),
        r"annotations\.json|illumination",
    ),
    (lambda d, r: d.pop(r.choice(["images", "annotations", "categories"])), r"annotations\.json"),
    (lambda d, r: d["images"][0].__setitem__("id", r.choice([None, "x", -1, 1.5])), r"annotations\.json|id"),
]


def _damaged_set(src: Path, dst: Path, rng: random.Random) -> str:
    folder = copy_tree(src, dst)
    kind = rng.randrange(len(COCO_DAMAGE) + 2)
    ann = folder / "annotations.json"
    if kind == len(COCO_DAMAGE):  # a cut file
        raw = ann.read_bytes()
        ann.write_bytes(raw[: rng.randrange(1, len(raw) - 1)])
        return r"annotations\.json"
    if kind == len(COCO_DAMAGE) + 1:  # an image that is not one
        data = json.loads(ann.read_text())
        img = folder / "images" / data["images"][0]["file_name"]
        img.write_bytes(rng.randbytes(rng.randrange(0, 64)))
        return re.escape(img.name)
    data = json.loads(ann.read_text())
    change, culprit = COCO_DAMAGE[kind]
    change(data, rng)
    ann.write_text(json.dumps(data))
    return culprit


@pytest.mark.parametrize("seed", SEEDS)
def test_detect_train_on_a_damaged_set_is_one_error_naming_it(tmp_path, street, seed):
    rng = random.Random(seed)
    culprit = _damaged_set(street, tmp_path / "set", rng)
    keep_file(tmp_path)
    check(
        tmp_path,
        ["detect", "train", tmp_path / "set", "--out", tmp_path / "run", "--steps", "1", "--batch", "1", "--quiet"],
        1,
        culprit,
    )


@pytest.mark.parametrize("seed", SEEDS)
def test_detect_eval_on_a_damaged_set_or_checkpoint_is_one_error_naming_it(tmp_path, street, detector_run, seed):
    import pickle

    import torch

    rng = random.Random(seed)
    run = copy_tree(detector_run, tmp_path / "run")
    data = street
    what = rng.choice(["set", "bytes", "pickle", "keys", "cut"])
    ck = run / "detector.pt"
    if what == "set":
        data = tmp_path / "set"
        culprit = _damaged_set(street, data, rng)
    elif what == "bytes":
        ck.write_bytes(rng.randbytes(rng.randrange(0, 200)))
        culprit = r"detector\.pt"
    elif what == "pickle":  # code in a pickle must never run
        ck.write_bytes(pickle.dumps(os.system))
        culprit = r"detector\.pt"
    elif what == "keys":
        state = torch.load(ck, weights_only=True)  # what evaluation needs (the optimizer it does not)
        key = rng.choice(["format", "config", "state_dict", "step", "wall_s", "a weight"])
        if key == "a weight":
            state["state_dict"].pop(rng.choice(sorted(state["state_dict"])))
        else:
            state.pop(key)
        torch.save(state, ck)
        culprit = r"detector\.pt|checkpoint"
    else:
        raw = ck.read_bytes()
        ck.write_bytes(raw[: rng.randrange(1, len(raw) - 1)])
        culprit = r"detector\.pt"
    check(tmp_path, ["detect", "eval", run, data], 1, culprit)


# -------------------------------------------------------------------------- optix metrics
def _png(width: int, height: int, payload: bytes) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(payload)) + chunk(b"IEND", b"")


@pytest.mark.parametrize("seed", SEEDS)
def test_metrics_on_a_damaged_image_is_one_error_naming_it(tmp_path, seed):
    from PIL import Image

    rng = random.Random(seed)
    ref = tmp_path / "ref.png"
    Image.fromarray(np.random.default_rng(seed).integers(0, 255, (40, 48, 3), dtype=np.uint8)).save(ref)
    bad = tmp_path / "bad.png"
    kind = rng.choice(["empty", "bytes", "cut", "bomb", "size", "float"])
    if kind == "empty":
        bad.write_bytes(b"")
    elif kind == "bytes":
        bad.write_bytes(rng.randbytes(rng.randrange(1, 300)))
    elif kind == "cut":
        raw = ref.read_bytes()
        bad.write_bytes(raw[: rng.randrange(8, len(raw) - 20)])
    elif kind == "bomb":
        bad.write_bytes(_png(60000, 60000, b"\0" * 64))
    elif kind == "size":
        Image.fromarray(np.zeros((24, 24, 3), np.uint8)).save(bad)
    else:
        bad = tmp_path / "bad.tiff"
        Image.fromarray(np.full((40, 48), np.nan, np.float32)).save(bad)
    args = ["metrics", bad, ref] if rng.random() < 0.5 else ["metrics", ref, bad]
    check(tmp_path, args + ["--json"], 1, re.escape(bad.name) + r"|size|shape", nothing_new=True)


# ------------------------------------------------------------- optix scenes street
@pytest.mark.parametrize("seed", SEEDS)
def test_street_scenes_never_replace_a_set(tmp_path, street, seed):
    rng = random.Random(seed)
    copy_tree(street, tmp_path / "set")
    size = rng.choice(["32x48", "64x96"])
    check(
        tmp_path,
        ["scenes", "street", "--out", tmp_path / "set", "-n", str(rng.randrange(1, 4)), "--size", size],
        1,
        r"--out|not empty|holds",
    )


# ----------------------------------------------------- lens files: info, psf, tolerance
def _flip_a_value(text: str, rng: random.Random) -> tuple[str, bool]:
    """Replace one number of a .zmx file by a hostile one; whether it must fail."""
    lines = text.splitlines()
    idx = [
        i
        for i, ln in enumerate(lines)
        if re.search(r"\d", ln)
        and ln.split()[0] in ("CURV", "DISZ", "ENPD", "WAVM", "YFLN", "DIAM", "CONI", "PARM", "GLAS", "FTYP", "SURF")
    ]
    i = rng.choice(idx)
    tok = lines[i].split()
    j = rng.randrange(1, len(tok))
    tok[j] = rng.choice(["nan", "inf", "-1e308", "1e308", "x", "", "1,5", "99999999999999999999"])
    lines[i] = "  " + " ".join(tok)
    return "\n".join(lines) + "\n", True


@pytest.mark.parametrize("seed", SEEDS)
def test_lens_commands_on_a_damaged_zmx_answer_or_name_file_and_line(tmp_path, seed):
    rng = random.Random(seed)
    text = (REPO / "tests" / "data" / "zmx" / "cooke_utf8.zmx").read_text(encoding="utf-8")
    bad, _ = _flip_a_value(text, rng)
    path = tmp_path / "lens.zmx"
    path.write_text(bad, encoding="utf-8")
    keep_file(tmp_path)
    command = rng.choice(
        [
            ["lens", "info", path, "--json"],
            ["psf", path, "--size", "16", "--pupil-samples", "16", "--out", tmp_path / "psf.npy"],
            ["lens", "convert", path, tmp_path / "lens.json"],
        ]
    )
    before = snapshot(tmp_path)
    res = invoke(command)
    assert "Traceback" not in res.output and res.exit_code in (0, 1), res.output
    if res.exit_code == 1:  # refused: one line naming the file and line
        errors = [ln for ln in res.output.splitlines() if ln.startswith("Error:")]
        assert len(errors) == 1 and re.search(r"lens\.zmx(:\d+)?", errors[0]), res.output
        assert snapshot(tmp_path) == before
    else:  # a value the lens can take (a changed glass index, a DIAM): finite answers
        assert not re.search(r"\b(nan|inf)\b", res.output, re.IGNORECASE), res.output
        assert not [p for p in snapshot(tmp_path) if p not in before and non_finite_in(p)]


@pytest.mark.parametrize("seed", SEEDS)
def test_tolerance_on_a_damaged_lens_file_is_one_error_naming_it(tmp_path, seed):
    from optix_e2e.lens import BUNDLED_DIR

    rng = random.Random(seed)
    data = json.loads((BUNDLED_DIR / "cooke-f50.json").read_text())
    s = rng.choice(data["surfaces"])
    key = rng.choice(["radius", "thickness", "material", "semi_diameter", "stop"])
    s[key] = rng.choice(["abc", [1], {"n": "x"}, -1e308, None if key in ("radius",) else "inf"])
    if key == "radius" and s[key] is None:
        s[key] = "abc"
    path = tmp_path / "lens.json"
    path.write_text(json.dumps(data))
    keep_file(tmp_path)
    check(
        tmp_path,
        ["tolerance", path, "--space", "cooke-f50", "--mc", "2", "--out", tmp_path / "tol"],
        1,
        r"lens\.json|surface",
    )


# -------------------------------------------------------------- optix dataset --dask
@pytest.mark.parametrize(
    "address, culprit",
    [
        ("tcp://256.1.1.1:1", r"256\.1\.1\.1|address|--dask"),
        ("tcp://host:99999", r"99999|port|--dask"),
        ("http://x:1", r"http|protocol|--dask"),
        ("ucx://", r"ucx|address|--dask"),
    ],
)
def test_dataset_with_a_dask_address_that_leads_nowhere_fails_at_once(tmp_path, address, culprit):
    keep_file(tmp_path)
    check(
        tmp_path,
        ["dataset", "generate", "cooke-f50", "-n", "2", "--out", tmp_path / "d", "--dask", address],
        1,
        culprit,
        nothing_new=True,
    )


# ---------------------------------------------------------------- optix lens survey
@pytest.mark.parametrize("seed", SEEDS)
def test_lens_survey_of_damaged_files_reports_them_and_writes_finite_files(tmp_path, seed):
    rng = random.Random(seed)
    folder = tmp_path / "lenses"
    folder.mkdir()
    text = (REPO / "tests" / "data" / "zmx" / "cooke_utf8.zmx").read_text(encoding="utf-8")
    for i in range(4):
        bad, _ = _flip_a_value(text, rng)
        raw = bad.encode("utf-8")
        if rng.random() < 0.3:
            raw = raw[: rng.randrange(1, len(raw))]
        (folder / f"lens{i}.zmx").write_bytes(raw)
    (folder / "garbage.zmx").write_bytes(rng.randbytes(500))
    keep_file(tmp_path)
    out = tmp_path / "survey"
    check(tmp_path, ["lens", "survey", folder, "--out", out], 0, "")
    summary = json.loads((out / "survey.json").read_text())
    assert summary["files"] == 5 and summary["imported"] <= 5


# ------------------------------------------------- optix surrogate train, design --surrogate
@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    from optix_e2e.dataset import DatasetSettings, generate

    out = tmp_path_factory.mktemp("probe") / "data"
    generate("paper-triplet-v1", 6, 3, out, DatasetSettings(shard_size=3), progress=False)
    return out


def _damage_dataset(root: Path, rng: random.Random) -> str:
    # (designs.csv is the sampling's record, not read by training: the shards hold the
    # parameters, so a changed designs.csv is `optix dataset verify`'s to report)
    kind = rng.choice(["manifest cut", "manifest key", "manifest value", "shard bytes", "shard json"])
    man = root / "manifest.json"
    shard = sorted((root / "shards").iterdir())[0]
    if kind == "manifest cut":
        raw = man.read_bytes()
        man.write_bytes(raw[: rng.randrange(1, len(raw) - 1)])
        return r"manifest\.json"
    if kind in ("manifest key", "manifest value"):
        data = json.loads(man.read_text())
        key = rng.choice(["space", "base_lens", "param_mean", "param_std", "settings", "format", "n_designs"])
        if kind == "manifest key" or key not in data:
            data.pop(key, None)
        else:
            data[key] = rng.choice(["x", -1, None, [float("nan")], {"a": 1}])
        man.write_text(json.dumps(data))
        return r"manifest|" + key
    if kind == "shard bytes":
        f = shard / rng.choice(["psf_sensor.npy", "params.npy", "design.npy"])
        raw = f.read_bytes()
        f.write_bytes(raw[: rng.randrange(0, len(raw) - 1)])
        return re.escape(shard.name) + "|" + re.escape(f.name)
    if kind == "shard json":
        (shard / "shard.json").write_text(rng.choice(["{", "[]", '{"crc32": 5}', "\x00"]))
        return re.escape(shard.name) + r"|shard\.json"


@pytest.mark.parametrize("seed", SEEDS)
def test_surrogate_train_on_a_damaged_dataset_is_one_error_naming_it(tmp_path, dataset, seed):
    rng = random.Random(seed)
    data = copy_tree(dataset, tmp_path / "data")
    culprit = _damage_dataset(data, rng)
    keep_file(tmp_path)
    check(
        tmp_path,
        [
            "surrogate",
            "train",
            data,
            "--out",
            tmp_path / "run",
            "--steps",
            "1",
            "--batch",
            "2",
            "--hidden",
            "8",
            "--depth",
            "1",
            "--base-channels",
            "4",
            "--n-up",
            "0",
            "--val-designs",
            "2",
        ],
        1,
        culprit,
    )


@pytest.mark.parametrize("seed", SEEDS)
def test_design_with_a_crafted_surrogate_is_one_error_naming_it(tmp_path, seed):
    import pickle

    rng = random.Random(seed)
    bad = tmp_path / "optics.pt"
    kind = rng.choice(["bytes", "pickle", "empty", "cut"])
    if kind == "bytes":
        bad.write_bytes(rng.randbytes(rng.randrange(1, 400)))
    elif kind == "pickle":
        bad.write_bytes(pickle.dumps(os.system))
    elif kind == "empty":
        bad.write_bytes(b"")
    else:
        from optix_e2e.lens import BUNDLED_DIR

        raw = (BUNDLED_DIR / "surrogate_paper_triplet_e2e.pt").read_bytes()
        bad.write_bytes(raw[: rng.randrange(1, len(raw) - 1)])
    keep_file(tmp_path)
    check(
        tmp_path,
        ["design", "iq-software", "--surrogate", bad, "--out", tmp_path / "out", "--budget", "smoke", "--quiet"],
        1,
        r"optics\.pt",
    )
