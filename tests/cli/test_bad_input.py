"""Bad input to the newer commands: one clear error naming the problem, nothing written.

The classes behind the probes of the "bad input" issue: every numeric design setting has a
range (finite, with a maximum where memory or threads follow from it), files read as text are
regular and small, JSON that cannot be written leaves nothing behind, thread counts are bounded.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os

import pytest
from click.testing import CliRunner

from optix_e2e.camera_design.config import RANGES, DesignConfig, make_config, read_config_file
from optix_e2e.cli import main
from optix_e2e.io import read_small_text, write_json_atomic
from optix_e2e.parallel import MAX_THREADS, set_threads


def test_every_numeric_design_setting_has_a_range():
    numeric = {f.name for f in dataclasses.fields(DesignConfig) if f.type in ("int", "float", int, float)}
    assert numeric and numeric == set(RANGES)
    for name, (lo, hi, _) in RANGES.items():
        default = getattr(DesignConfig, name)
        assert lo <= default <= hi, name  # the defaults pass their own check


@pytest.mark.parametrize(
    "line, words",
    [
        ("threads = 50000", ["threads", "1024"]),
        ("batch = 9223372036854775807", ["batch", "256"]),
        ("lr_optics = inf", ["lr_optics", "finite"]),
        ("beta_isp = nan", ["beta_isp", "finite"]),
        ("eval_procedural = 100000000", ["eval_procedural"]),
        ("lr_isp_net = 0.0", ["lr_isp_net", "> 0"]),
        ("bootstrap = 10", ["bootstrap", ">= 100"]),
    ],
)
def test_a_setting_out_of_range_names_the_file_and_the_setting(tmp_path, line, words):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(line + "\n")
    with pytest.raises(ValueError) as err:
        make_config("smoke", cfg)
    msg = str(err.value)
    assert str(cfg) in msg and all(w in msg for w in words), msg


def test_an_override_out_of_range_is_refused_too():
    with pytest.raises(ValueError, match="threads must be >= 0 and <= 1024"):
        make_config("smoke", threads=MAX_THREADS + 1)
    with pytest.raises(ValueError, match="eval_level must be a finite number"):
        make_config("smoke", eval_level=math.nan)


def test_a_pipe_or_a_device_is_not_read_as_a_config_file(tmp_path):
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)  # reading it would block forever
    with pytest.raises(ValueError, match="not a regular file"):
        read_config_file(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        read_config_file(tmp_path)
    if os.path.exists("/dev/zero"):
        with pytest.raises(ValueError, match="/dev/zero: the config file is not a regular file"):
            read_config_file(type(tmp_path)("/dev/zero"))
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (1 << 20) + "\n")
    with pytest.raises(ValueError, match="larger than"):
        read_config_file(big)
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ValueError, match=str(deep)):
        read_config_file(deep)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match="not UTF-8"):
        read_small_text(binary)


def test_json_that_cannot_be_written_leaves_nothing_behind(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"kept": true}\n')
    for bad in ({"lr": math.inf}, {"x": math.nan}, {"f": object()}):
        with pytest.raises(ValueError, match="config.json: cannot be written as JSON"):
            write_json_atomic(path, bad)
    assert json.loads(path.read_text()) == {"kept": True}  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.json"]  # no stray .tmp file


def test_thread_counts_are_bounded():
    for bad in (-1, MAX_THREADS + 1, 50_000, 1.5, True):
        with pytest.raises(ValueError, match="threads must be an integer"):
            set_threads(bad)
    set_threads(0)  # torch's default, unchanged


@pytest.mark.parametrize(
    "args",
    [
        ["design", "iq-software", "--budget", "smoke", "--threads", "50000"],
        ["detect", "train", ".", "--threads", "50000"],
        ["surrogate", "train", ".", "--threads", "50000"],
    ],
)
def test_cli_refuses_huge_thread_counts_before_claiming_a_folder(tmp_path, args):
    out = tmp_path / "run"
    res = CliRunner().invoke(main, [*args, "--out", str(out)])
    assert res.exit_code == 2, res.output
    assert "--threads" in res.output and "0<=x<=1024" in res.output
    assert not out.exists()


# ----- diverging training: one error naming the step, the last good checkpoint kept ----------
def test_a_diverging_surrogate_training_stops_and_keeps_the_good_state(tmp_path):
    import torch

    from optix_e2e.dataset import DatasetSettings, generate
    from optix_e2e.parallel import TrainingDiverged
    from optix_e2e.surrogate.train import TrainConfig, train

    data = tmp_path / "data"
    generate("paper-triplet-v1", 12, 3, data, DatasetSettings(shard_size=12), progress=False)
    tiny = dict(
        hidden=16, depth=1, base_channels=8, n_up=2, batch=8, val_designs=4, val_every=5, warmup=1, device="cpu"
    )
    with pytest.raises(TrainingDiverged, match=r"training diverged at step \d+: the (loss|weights)"):
        train(data, tmp_path / "wild", TrainConfig(steps=40, lr=1e30, **tiny), progress=False)
    state = tmp_path / "wild" / "state.pt"
    if state.exists():  # whatever was saved before the divergence is finite
        saved = torch.load(state, weights_only=True)
        assert all(torch.isfinite(v).all() for v in saved["model"].values() if v.is_floating_point())
    assert not (tmp_path / "wild" / "train.json").exists()  # no summary full of NaN
    # a state whose weights are not finite is refused on resume, naming the file
    train(data, tmp_path / "ok", TrainConfig(steps=5, **tiny), progress=False)
    st = torch.load(tmp_path / "ok" / "state.pt", weights_only=True)
    first = next(k for k, v in st["model"].items() if v.is_floating_point())
    st["model"][first] = st["model"][first] * float("nan")
    torch.save(st, tmp_path / "ok" / "state.pt")
    with pytest.raises(ValueError, match=r"state.pt: damaged surrogate training state.*weights are not finite"):
        train(data, tmp_path / "ok", TrainConfig(steps=10, **tiny), progress=False)
    good = torch.load(tmp_path / "ok" / "state.pt", weights_only=True)
    good["model"][first] = torch.zeros_like(good["model"][first])
    for change, words in (
        (lambda st: st.pop("step"), "KeyError"),
        (lambda st: st.update(step=10**9), "step"),
        (lambda st: st.update(seconds=float("nan")), "seconds nan"),
        (lambda st: st.pop("data"), "no data record"),
    ):
        st = dict(good)
        change(st)
        torch.save(st, tmp_path / "ok" / "state.pt")
        with pytest.raises(ValueError, match="damaged surrogate training state") as err:
            train(data, tmp_path / "ok", TrainConfig(steps=10, **tiny), progress=False)
        assert words in str(err.value)
    other = tmp_path / "design-run"  # another run's folder: refused, untouched
    other.mkdir()
    (other / "config.json").write_text("{}\n")
    with pytest.raises(ValueError, match="holds no surrogate training"):
        train(data, other, TrainConfig(steps=5, **tiny), progress=False)
    assert sorted(p.name for p in other.iterdir()) == ["config.json"]


def test_a_diverging_detector_training_stops_and_another_run_folder_is_refused(tmp_path):
    import torch

    from optix_e2e.parallel import TrainingDiverged
    from optix_e2e.scenes.coco import write_street_coco
    from optix_e2e.tasks.detector_train import train_detector

    write_street_coco(tmp_path / "data", 4, (64, 96), seed=0)
    with pytest.raises(TrainingDiverged, match=r"training diverged at step \d+"):
        train_detector(
            tmp_path / "data",
            tmp_path / "wild",
            steps=30,
            batch=2,
            lr=1e30,
            checkpoint_every=1,
            progress=False,
            log=lambda m: None,
        )
    if not (tmp_path / "wild" / "detector.pt").exists():  # stopped before a checkpoint: it starts again there
        assert (
            train_detector(tmp_path / "data", tmp_path / "wild", steps=2, batch=2, progress=False, log=lambda m: None)[
                "steps"
            ]
            == 2
        )
    if (tmp_path / "wild" / "detector.pt").exists():  # a checkpoint from before the divergence: finite
        from optix_e2e.tasks.detector_train import load_detector

        model, _ = load_detector(tmp_path / "wild")
        assert all(torch.isfinite(v).all() for v in model.state_dict().values() if v.is_floating_point())
    other = tmp_path / "design-run"
    other.mkdir()
    (other / "history.csv").write_text("step,loss_optics\n1,0.5\n")
    with pytest.raises(ValueError, match="holds no detector run"):
        train_detector(tmp_path / "data", other, steps=2, batch=2, progress=False, log=lambda m: None)
    assert (other / "history.csv").read_text() == "step,loss_optics\n1,0.5\n"
    assert sorted(p.name for p in other.iterdir()) == ["history.csv"]


# ----- optix metrics: the file's own depth, no bombs, no inf -----------------------------------
def _png_header_only(path, width: int, height: int) -> None:
    """A PNG that claims width x height (8-bit grey) with one tiny, truncated IDAT."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def test_metrics_reads_16_bit_files_at_their_depth_and_refuses_what_it_cannot_read(tmp_path):
    import numpy as np
    from PIL import Image

    a = (np.random.default_rng(0).random((40, 48)) * 65535).astype(np.uint16)
    Image.fromarray(a).save(tmp_path / "g16.png")
    Image.fromarray((a / 257).round().astype(np.uint8)).save(tmp_path / "g8.png")
    res = CliRunner().invoke(main, ["metrics", str(tmp_path / "g16.png"), str(tmp_path / "g8.png"), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["psnr_db"] > 50  # the same picture: only 8-bit rounding apart (was 4.8 dB)
    Image.fromarray(np.zeros((40, 48), np.float32)).save(tmp_path / "f.tif")
    _png_header_only(tmp_path / "bomb.png", 100_000, 100_000)  # PIL's own bomb limit
    _png_header_only(tmp_path / "big.png", 9000, 8000)  # under PIL's, over ours (64 Mpixel)
    for bad, words in (
        ("f.tif", "floating-point images are not read"),
        ("bomb.png", "too large to decode safely"),
        ("big.png", "9000x8000 pixels is more than"),
    ):
        res = CliRunner().invoke(main, ["metrics", str(tmp_path / bad), str(tmp_path / "g8.png")])
        assert res.exit_code == 1 and words in res.output and "Traceback" not in res.output, res.output


def test_haarpsi_of_two_identical_images_without_structure_is_one(tmp_path):
    import torch
    from PIL import Image

    from optix_e2e.metrics.image import haarpsi

    black = torch.zeros(2, 3, 32, 32)
    assert torch.equal(haarpsi(black, black), torch.ones(2))
    assert 0 < float(haarpsi(black[:1], black[:1] + 0.01)[0]) < 1
    Image.new("RGB", (32, 32)).save(tmp_path / "black.png")
    res = CliRunner().invoke(main, ["metrics", str(tmp_path / "black.png"), str(tmp_path / "black.png"), "--json"])
    assert res.exit_code == 0 and json.loads(res.output)["haarpsi"] == 1.0, res.output


def test_metrics_refuses_images_smaller_than_lpips_windows(tmp_path):
    """LPIPS's AlexNet reaches relu5 only from 31 x 31 pixels: a 24 x 20 pair, or a crop that
    leaves less, is one line naming the size (was a traceback from a max-pool); 31 x 31 scores."""
    import torch
    from PIL import Image

    from optix_e2e.errors import InputError
    from optix_e2e.metrics.lpips import LPIPS_MIN_SIZE, lpips

    for w, h, crop in ((24, 20, 0), (48, 48, 9), (31, 31, 0)):
        Image.new("RGB", (w, h), (90, 120, 40)).save(tmp_path / "a.png")
        Image.new("RGB", (w, h), (80, 120, 40)).save(tmp_path / "b.png")
        res = CliRunner().invoke(
            main, ["metrics", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--crop", str(crop)]
        )
        if min(w, h) - 2 * crop >= LPIPS_MIN_SIZE:
            assert res.exit_code == 0, res.output
        else:
            assert res.exit_code == 1 and "LPIPS" in res.output and "Traceback" not in res.output, res.output
    with pytest.raises(InputError, match="at least 31x31"):
        lpips(torch.rand(1, 3, 30, 64), torch.rand(1, 3, 30, 64))
    assert lpips(torch.rand(1, 3, 31, 31), torch.rand(1, 3, 31, 31)).isfinite().all()


@pytest.mark.timeout(60)
def test_a_fifo_where_a_file_is_read_is_refused_not_waited_on(tmp_path):
    """A named pipe where an image, a torch checkpoint or a COCO annotation file is read: one
    line naming it (a read would block for ever: nothing writes to the pipe)."""
    from optix_e2e.errors import InputError
    from optix_e2e.tasks.detector_train import load_coco_folder
    from optix_e2e.torchfile import load_plain

    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)
    Image = pytest.importorskip("PIL.Image")
    Image.new("RGB", (40, 40)).save(tmp_path / "ok.png")
    res = CliRunner().invoke(main, ["metrics", str(fifo), str(tmp_path / "ok.png")])
    assert res.exit_code == 1 and "not a regular file" in res.output, res.output
    with pytest.raises(InputError, match="not a regular file"):
        load_plain(fifo, "software ISP checkpoint")
    coco = tmp_path / "coco"
    (coco / "images").mkdir(parents=True)
    os.mkfifo(coco / "annotations.json")
    with pytest.raises(InputError, match="annotation file is not a regular file"):
        load_coco_folder(coco)


def test_isp_tune_does_not_write_over_a_detect_tunes_record(tmp_path):
    """A killed ``detect tune`` leaves its tune.json alone in its folder: ``isp tune --out`` there
    is refused before any work (it wrote its own tune.json over the detector's record)."""
    record = '{"tuned_from": {"crop": 192}}'
    (tmp_path / "tune.json").write_text(record)
    res = CliRunner().invoke(
        main, ["isp", "tune", "--steps", "1", "--scenes", "2", "--size", "32", "--out", str(tmp_path)]
    )
    assert res.exit_code == 1 and "choose another --out" in res.output, res.output
    assert [p.name for p in tmp_path.iterdir()] == ["tune.json"] and (tmp_path / "tune.json").read_text() == record


def test_error_messages_escape_control_bytes():
    from optix_e2e.cli._common import _one_line

    msg = _one_line(ValueError("x.zmx line 3: unknown glass '\x1b]0;pwned\x07N-BK7\u202e'"))
    assert "\x1b" not in msg and "\x07" not in msg and "\u202e" not in msg
    assert "\\x1b]0;pwned\\x07N-BK7\\u202e" in msg


# ----- commands that write into --out: nothing they did not write is replaced ------------------
def test_street_scenes_refuse_a_folder_that_holds_a_set_and_take_small_frames(tmp_path):
    from optix_e2e.scenes.coco import write_street_coco

    first = tmp_path / "set"
    write_street_coco(first, 3, (48, 64), seed=0)
    before = sorted(p.relative_to(first) for p in first.rglob("*"))
    res = CliRunner().invoke(main, ["scenes", "street", "--out", str(first), "-n", "2", "--quiet"])
    assert res.exit_code == 1 and "is not an empty folder" in res.output, res.output
    assert sorted(p.relative_to(first) for p in first.rglob("*")) == before
    assert len(json.loads((first / "annotations.json").read_text())["images"]) == 3
    # every size the help allows works (32 rows: objects once drew from an empty range)
    for size in ("32x48", "48x32", "32x32"):
        res = CliRunner().invoke(
            main, ["scenes", "street", "--out", str(tmp_path / size), "-n", "6", "--size", size, "--quiet"]
        )
        assert res.exit_code == 0, res.output
    for size in ("100000x100000", "31x64", "64", "axb"):
        res = CliRunner().invoke(main, ["scenes", "street", "--out", str(tmp_path / "x"), "-n", "1", "--size", size])
        assert res.exit_code == 2 and "--size" in res.output and not (tmp_path / "x").exists(), res.output


def test_lens_survey_names_any_file_name_in_utf8_and_writes_its_files_whole(tmp_path):
    from pathlib import Path

    folder = tmp_path / "zmx"
    folder.mkdir()
    text = (Path(__file__).parents[1] / "data" / "zmx" / "cooke_utf8.zmx").read_text(encoding="utf-8")
    (folder / "ok.zmx").write_text(text)
    odd = os.fsdecode(bytes(folder) + b"/odd\xff\x1b.zmx")  # not UTF-8, and an escape byte
    with open(odd, "w") as f:
        f.write(text)
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["lens", "survey", str(folder), "--out", str(out)])
    assert res.exit_code == 0, res.output
    table = (out / "survey.csv").read_bytes().decode("utf-8")  # valid UTF-8
    assert "odd\\xff\\x1b.zmx,True" in table and "\x1b" not in table
    rows = [r for r in table.splitlines()[1:] if r]
    assert len(rows) == 2 and all(",True,True," in r for r in rows), table  # both import and trace
    assert "\x1b" not in res.output
    assert json.loads((out / "survey.json").read_text())["imported"] == 2
    # a refused file whose text holds an escape sequence: the reason is shown escaped
    (folder / "evil.zmx").write_text(text.replace("DISZ ", "DISZ \x1b]0;pwned\x07", 1))
    res = CliRunner().invoke(main, ["lens", "survey", str(folder), "--out", str(out)])
    assert res.exit_code == 0 and "\x1b" not in res.output and "\x07" not in res.output, res.output
    assert "\x1b" not in (out / "survey.csv").read_text() and "\\x1b]0;pwned" in (out / "survey.csv").read_text()


def test_lens_info_and_convert_show_a_zmx_names_escape_bytes_escaped(tmp_path):
    """A .zmx NAME (and so the lens's name) holding a terminal escape (set the title, ring the
    bell): ``lens info`` and ``lens convert`` print it escaped, never the bytes themselves."""
    from pathlib import Path

    text = (Path(__file__).parents[1] / "data" / "zmx" / "cooke_utf8.zmx").read_text(encoding="utf-8")
    lines = [ln for ln in text.splitlines() if not ln.startswith("NAME ")]
    evil = tmp_path / "evil.zmx"
    evil.write_text("NAME \x1b]0;pwned\x07Cooke\u202e\n" + "\n".join(lines) + "\n", encoding="utf-8")
    for args in (["lens", "info", str(evil)], ["lens", "convert", str(evil), str(tmp_path / "out.json")]):
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 0, res.output
        assert not any(c in res.output for c in "\x1b\x07\u202e"), res.output
    assert "\\x1b]0;pwned\\x07Cooke\\u202e" in CliRunner().invoke(main, ["lens", "info", str(evil)]).output


# ----- COCO sets: names stay inside, categories the detector knows, finite extras ----------------
def _street_set(tmp_path, n=2):
    from optix_e2e.scenes.coco import write_street_coco

    folder = tmp_path / "set"
    write_street_coco(folder, n, (48, 64), seed=1)
    return folder, json.loads((folder / "annotations.json").read_text())


def test_coco_file_names_cannot_leave_the_image_folder(tmp_path):
    from optix_e2e.scenes.coco import CocoDetection, CocoFormatError

    folder, data = _street_set(tmp_path)
    (tmp_path / "secret.png").write_bytes((folder / "images" / data["images"][0]["file_name"]).read_bytes())
    for name in ("../../secret.png", str(tmp_path / "secret.png"), "../secret.png", "a/../../secret.png", "x\x00.png"):
        bad = json.loads(json.dumps(data))
        bad["images"][0]["file_name"] = name
        (folder / "annotations.json").write_text(json.dumps(bad))
        with pytest.raises(CocoFormatError, match="leaves the image folder"):
            CocoDetection(folder / "images", folder / "annotations.json")
    # a link the folder's owner put there is followed (shared image stores, git-annex)
    os.symlink(tmp_path / "secret.png", folder / "images" / "link.png")
    ok = json.loads(json.dumps(data))
    ok["images"][0]["file_name"] = "link.png"
    (folder / "annotations.json").write_text(json.dumps(ok))
    assert CocoDetection(folder / "images", folder / "annotations.json")[0][0].shape[0] == 3


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda d: d["annotations"][0].__setitem__("illumination", float("nan")), "illumination must be a finite"),
        (lambda d: d["annotations"][0].__setitem__("illumination", -1), "illumination must be a finite"),
    ],
)
def test_coco_extras_must_be_finite(tmp_path, change, words):
    from optix_e2e.scenes.coco import CocoDetection, CocoFormatError

    folder, data = _street_set(tmp_path)
    assert data["annotations"], "the set needs an object"
    change(data)
    (folder / "annotations.json").write_text(json.dumps(data))  # NaN as the JSON token NaN
    with pytest.raises(CocoFormatError, match=words):
        CocoDetection(folder / "images", folder / "annotations.json")


@pytest.mark.parametrize("cid", [-1, 0, 5, 7])
def test_the_detector_refuses_categories_it_does_not_have(tmp_path, cid):
    from optix_e2e.tasks.detector_train import load_coco_folder

    folder, data = _street_set(tmp_path)
    data["categories"].append({"id": cid, "name": "boat"})
    data["annotations"][0]["category_id"] = cid
    (folder / "annotations.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=f"category {cid} 'boat' is not one the detector knows"):
        load_coco_folder(folder)
    data["categories"] = [{"id": 1, "name": "car"}]  # a known id under another name
    (folder / "annotations.json").write_text(json.dumps({**data, "annotations": []}))
    with pytest.raises(ValueError, match="category 1 'car'"):
        load_coco_folder(folder)


def test_detect_eval_on_a_set_without_objects_is_an_error_not_a_map_of_minus_one(tmp_path):
    from optix_e2e.tasks.detector import make_detector
    from optix_e2e.tasks.detector_train import evaluate_detector

    folder, data = _street_set(tmp_path)
    (folder / "annotations.json").write_text(json.dumps({**data, "annotations": []}))
    with pytest.raises(ValueError, match="no objects to score"):
        evaluate_detector(make_detector(32, 64, (48, 64)), folder)


def test_every_numeric_command_line_option_is_finite_and_counts_have_a_maximum():
    # the class behind "--threads 50000 segfaults", "batch 2**63 hangs", "--lr inf": every
    # integer option of every command has a maximum, every float option refuses nan and inf
    import click

    from optix_e2e.cli._common import FiniteFloatRange

    def options(cmd, path):
        if isinstance(cmd, click.Group):
            for name, sub in cmd.commands.items():
                yield from options(sub, [*path, name])
        else:
            for p in cmd.params:
                yield " ".join([*path, p.opts[0] if p.opts else p.name]), p.type

    bad = []
    for name, t in options(main, []):
        if isinstance(t, click.types.IntParamType) and (not isinstance(t, click.IntRange) or t.max is None):
            bad.append(f"{name}: an integer without a maximum")
        elif isinstance(t, click.types.FloatParamType) and not isinstance(t, FiniteFloatRange):
            bad.append(f"{name}: a float that lets nan or inf through")
    assert bad == []


# ----- states, checkpoints: values out of reason are refused, naming the file --------------------
def test_a_design_state_with_a_step_beyond_its_run_is_damaged(tmp_path):
    import torch

    from optix_e2e.camera_design.alg1 import Block, Vanilla
    from optix_e2e.camera_design.training import _load_state, _save_state

    w = torch.nn.Linear(2, 1)
    opt = Vanilla([Block("isp", list(w.parameters()), 1e-3)], 1e-3, 6)
    path = tmp_path / "end_to_end_state.pt"
    _save_state(path, w, opt, 1.0, [])
    assert _load_state(path, w, Vanilla([Block("isp", list(w.parameters()), 1e-3)], 1e-3, 6)) == (1.0, [])
    st = torch.load(path, weights_only=True)
    for key, value, words in (
        ("t", 10**6, "step 1000000 outside this run's 0..6"),
        ("t", -1, "step -1"),
        ("t", float("inf"), "OverflowError"),
    ):
        bad = {**st, "optimizer": {**st["optimizer"], key: value}}
        torch.save(bad, path)
        with pytest.raises(ValueError, match="damaged design checkpoint") as err:
            _load_state(path, w, Vanilla([Block("isp", list(w.parameters()), 1e-3)], 1e-3, 6))
        assert words in str(err.value) and str(path) in str(err.value)
    torch.save({**st, "wall_s": float("nan")}, path)
    with pytest.raises(ValueError, match="damaged design checkpoint.*wall_s nan"):
        _load_state(path, w, Vanilla([Block("isp", list(w.parameters()), 1e-3)], 1e-3, 6))


def test_damaged_detector_checkpoints_are_named_not_tracebacks(tmp_path):
    import torch

    from optix_e2e.scenes.coco import write_street_coco
    from optix_e2e.tasks.detector_train import train_detector

    write_street_coco(tmp_path / "data", 2, (48, 64), seed=0)
    run = tmp_path / "run"
    train_detector(tmp_path / "data", run, steps=1, batch=1, progress=False, log=lambda m: None)
    good = torch.load(run / "detector.pt", weights_only=True)
    for change, words in (
        (lambda c: c.pop("step"), "step missing"),
        (lambda c: c.update(step=10**12), "step"),
        (lambda c: c.update(wall_s=float("inf")), "wall_s inf"),
        (lambda c: c.update(optimizer={"state": 3}), "optimizer"),
    ):
        ck = dict(good)
        change(ck)
        torch.save(ck, run / "detector.pt")
        with pytest.raises(ValueError, match="damaged detector checkpoint") as err:
            train_detector(tmp_path / "data", run, steps=2, batch=1, progress=False, log=lambda m: None)
        assert words in str(err.value)


def test_a_damaged_evaluation_cache_is_evaluated_again_not_a_traceback(tmp_path):
    from optix_e2e.camera_design.image_quality import read_eval_cache

    path = tmp_path / "eval_nominal_exact.json"
    row = {
        "image": "photo:a",
        "position": "frame",
        "radius": 0.3,
        "psnr_db": 25.0,
        "ssim": 0.8,
        "lpips": 0.1,
        "haarpsi": 0.7,
    }
    path.write_text(json.dumps({"key": "k", "rows": [row]}))
    assert read_eval_cache(path, "k")["rows"] == [row]
    for rows in (
        [{**row, "psnr_db": "x"}],
        [{k: v for k, v in row.items() if k != "ssim"}],
        [3],
        [{**row, "image": 1}],
    ):
        path.write_text(json.dumps({"key": "k", "rows": rows}))
        assert read_eval_cache(path, "k") is None
    path.write_bytes(b"\xff\xfe garbage")
    assert read_eval_cache(path, "k") is None


def test_stop_if_diverged_names_the_step_and_what_left_the_finite_numbers(tmp_path):
    import torch

    from optix_e2e.parallel import TrainingDiverged, stop_if_diverged

    net = torch.nn.Linear(2, 2)
    stop_if_diverged(3, None, loss=0.5, net=net)  # all finite: nothing happens
    kept = tmp_path / "state.pt"
    kept.write_bytes(b"x")
    with pytest.raises(
        TrainingDiverged,
        match=r"^training diverged at step 7: the loss is nan; the last good "
        r"checkpoint \(.*state.pt\) is kept; lower the rate$",
    ):
        stop_if_diverged(7, kept, "lower the rate", loss=torch.tensor(float("nan")))
    with torch.no_grad():
        net.bias[1] = float("inf")
    with pytest.raises(TrainingDiverged, match=r"step 8: the weights \(bias\) are not finite"):
        stop_if_diverged(8, tmp_path / "absent.pt", loss=1.0, net=net)


@pytest.mark.parametrize(
    "change",
    [
        lambda st: st.update(param_std=[0.0] * len(st["param_std"])),
        lambda st: st.update(param_min=st["param_max"], param_max=st["param_min"]),
        lambda st: st.update(param_mean=[v + 1e6 for v in st["param_mean"]]),
        lambda st: st.update(pitch_um=-5.86),
    ],
)
def test_a_surrogate_with_a_normalization_out_of_reason_is_refused(change):
    import torch

    from optix_e2e.surrogate import OpticsSurrogate
    from optix_e2e.surrogate.checkpoint import SurrogateFileError, resolve

    st = torch.load(resolve("paper-triplet-v1"), weights_only=True)
    OpticsSurrogate.from_state(st, "ok.pt")
    change(st)
    with pytest.raises(SurrogateFileError, match="bad.pt: damaged surrogate checkpoint"):
        OpticsSurrogate.from_state(st, "bad.pt")


def test_a_surrogate_whose_manifest_lost_its_space_is_named():
    import torch

    from optix_e2e.surrogate import OpticsSurrogate
    from optix_e2e.surrogate.checkpoint import SurrogateFileError, resolve

    st = torch.load(resolve("paper-triplet-v1"), weights_only=True)
    for change in (
        lambda m: m.pop("space"),
        lambda m: m.update(space={"parameters": [3]}),
        lambda m: m.update(space={"parameters": [{"nme": "x"}]}),
        lambda m: m.pop("base_lens"),
    ):
        man = json.loads(json.dumps(st["manifest"]))
        change(man)
        with pytest.raises(SurrogateFileError, match="bad.pt: damaged surrogate checkpoint: .*manifest"):
            OpticsSurrogate.from_state({**st, "manifest": man}, "bad.pt")


def test_json_nested_too_deeply_is_one_error_naming_the_file(tmp_path):
    from optix_e2e.scenes.coco import CocoDetection, CocoFormatError

    deep = "[" * 200_000 + "]" * 200_000
    (tmp_path / "images").mkdir()
    (tmp_path / "annotations.json").write_text(deep)
    with pytest.raises(CocoFormatError, match="annotations.json: invalid JSON: nested too deeply"):
        CocoDetection(tmp_path / "images", tmp_path / "annotations.json")
    (tmp_path / "space.json").write_text(deep)
    res = CliRunner().invoke(
        main, ["sample", str(tmp_path / "space.json"), "-n", "1", "--out", str(tmp_path / "s.csv")]
    )
    assert res.exit_code == 1 and "space.json: invalid JSON: nested too deeply" in res.output, res.output
    assert not (tmp_path / "s.csv").exists()


def test_claim_out_dir_accepts_only_an_empty_folder_its_own_run_or_its_own_files(tmp_path):
    """The one rule behind every --out: absent, empty, this kind's run (its marker), or only
    the files this command writes (and what ``own`` accepts) is fine; anything else is one
    error naming the folder and a few of the files it did not write."""
    from optix_e2e.io import claim_out_dir

    assert claim_out_dir(tmp_path / "new", "x run", {"a.json"}) is False
    (tmp_path / "empty").mkdir()
    assert claim_out_dir(tmp_path / "empty", "x run") is False
    run = tmp_path / "run"
    run.mkdir()
    (run / "a.json").write_text("{}")
    assert claim_out_dir(run, "x run", {"a.json"}) is False  # its own files
    with pytest.raises(ValueError, match="holds no x run but a.json"):  # its names, not its content
        claim_out_dir(run, "x run", {"a.json"}, own=lambda p: False)
    (run / "state.pt").write_bytes(b"")
    assert claim_out_dir(run, "x run", marker="state.pt") is True  # its own run: resume
    other = tmp_path / "other"
    other.mkdir()
    for name in ("history.csv", "detector.pt", "notes.md", "z.txt"):
        (other / name).write_text("x")
    with pytest.raises(
        ValueError,
        match=r"other is not empty and holds no x run \(state\.pt\) but detector\.pt, "
        r"history\.csv, notes\.md, \.\.\.; choose another --out",
    ):
        claim_out_dir(other, "x run", marker="state.pt")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is not a folder"):
        claim_out_dir(tmp_path / "file", "x run")


@pytest.mark.parametrize(
    "args",
    [
        ["tolerance", "cooke-f50", "--space", "cooke-f50", "--mc", "0"],
        ["bench", "accuracy", "--quick"],
        ["lens", "report", "cooke-f50"],
        ["sensor", "ptc", "--levels", "10", "--patch", "32"],
        ["demo", "--n-fields", "2", "--size", "16", "--pupil-samples", "16"],
    ],
)
def test_report_commands_refuse_a_folder_of_another_run(tmp_path, args):
    from click.testing import CliRunner

    from optix_e2e.cli import main

    other = tmp_path / "other"
    other.mkdir()
    (other / "detector.pt").write_bytes(b"weights")
    res = CliRunner().invoke(main, [*args, "--out", str(other)])
    assert res.exit_code == 1 and "holds no" in res.output and "detector.pt" in res.output, res.output
    assert sorted(p.name for p in other.iterdir()) == ["detector.pt"]
    assert (other / "detector.pt").read_bytes() == b"weights"
