"""Corpora of real photographs (scenes/corpus.py): preparation from a source's checkout with
its manifest, the roles that keep the test split untouched, native-scale views, the test
split's samples, and ISP pre-training on photographs. The photographs here are made by the
tests (a tiny sample laid out as the sources are)."""

from __future__ import annotations

import hashlib
import json

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from click.testing import CliRunner

from optix_e2e.cli import main
from optix_e2e.color import linear_to_srgb, srgb_to_linear
from optix_e2e.errors import InputError
from optix_e2e.scenes.corpus import SOURCES, PhotoCorpus, prepare_corpus
from optix_e2e.scenes.natural import PHOTO_MIX, natural_scene
from optix_e2e.tasks.samples import TEST_NOISE0, SensorFrame, photo_test_set

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _photo(seed: int, h: int, w: int) -> np.ndarray:
    """A smooth random colour image with some texture (uint8 [h, w, 3])."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    base = np.stack([np.sin(6 * xx + c) * np.cos(4 * yy - c) for c in rng.uniform(0, 3, 3)], -1)
    return np.clip(127 + 100 * base + rng.normal(0, 10, (h, w, 3)), 0, 255).astype(np.uint8)


@pytest.fixture()
def bsds_checkout(tmp_path):
    """A checkout laid out as BSDS500's: 3 train, 2 test and 1 val photograph."""
    root = tmp_path / "BSDS500-checkout"
    for folder, n in (("train", 3), ("test", 2), ("val", 1)):
        d = root / "BSDS500" / "data" / "images" / folder
        d.mkdir(parents=True)
        for i in range(n):
            h, w = (321, 481) if i % 2 == 0 else (481, 321)
            iio.imwrite(d / f"{folder}{i}.png", _photo(10 * len(folder) + i, h, w))
    (root / "BSDS500" / "data" / "images" / "train" / "Thumbs.db").write_bytes(b"x")  # not an image: skipped
    return root


def test_a_source_is_prepared_with_its_manifest_and_its_test_folder_left_out(bsds_checkout, tmp_path):
    out = tmp_path / "corpus"
    m = prepare_corpus("bsds500", bsds_checkout, out, val_fraction=0.5)
    assert m["role"] == "train" and m["licence"] == SOURCES["bsds500"].licence
    assert len(m["files"]) == 5 and not any("val" in f["origin"].split("/")[-2] for f in m["files"])
    assert m["counts"]["train"] + m["counts"]["val"] == 5 and m["counts"]["test"] == 0
    for f in m["files"]:  # byte-identical copies, their sha256 and size recorded
        data = (out / f["file"]).read_bytes()
        assert data == (bsds_checkout / f["origin"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == f["sha256"]
        assert (f["height"], f["width"]) in ((321, 481), (481, 321))
        # the split is the sha256's, not the file order's
        assert f["split"] == ("val" if int(f["sha256"][:8], 16) < 0.5 * 16**8 else "train")
    assert json.loads((out / "manifest.json").read_text()) == m
    again = prepare_corpus("bsds500", bsds_checkout, out, val_fraction=0.5)  # the same preparation: the same corpus
    assert again["digest"] == m["digest"] and again["files"] == m["files"]


def test_preparation_refuses_what_it_cannot_hold(bsds_checkout, tmp_path):
    with pytest.raises(InputError, match="unknown photo source 'div2k'"):
        prepare_corpus("div2k", bsds_checkout, tmp_path / "a")
    with pytest.raises(InputError, match="has no folder testsets/Kodak24"):
        prepare_corpus("kodak24", bsds_checkout, tmp_path / "a")
    with pytest.raises(InputError, match="needs --licence"):
        prepare_corpus("folder", bsds_checkout, tmp_path / "a")
    with pytest.raises(InputError, match="own licence and role"):
        prepare_corpus("bsds500", bsds_checkout, tmp_path / "a", licence="mine")
    assert not (tmp_path / "a").exists()
    # a folder that holds other files is left as it was
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="notes.txt"):
        prepare_corpus("bsds500", bsds_checkout, other)
    assert [p.name for p in other.iterdir()] == ["notes.txt"]
    # an unreadable image names its file, and no manifest is written
    bad = bsds_checkout / "BSDS500" / "data" / "images" / "test" / "broken.jpg"
    bad.write_bytes(b"\xff\xd8 not a jpeg")
    with pytest.raises(InputError, match="broken.jpg"):
        prepare_corpus("bsds500", bsds_checkout, tmp_path / "b")
    assert not (tmp_path / "b" / "manifest.json").exists()
    bad.unlink()
    small = tmp_path / "small"
    small.mkdir()
    iio.imwrite(small / "tiny.png", _photo(0, 100, 300))
    with pytest.raises(InputError, match="tiny.png: 100 x 300 pixels"):
        prepare_corpus("folder", small, tmp_path / "c", licence="CC0")


def test_the_test_split_is_never_training_data_and_training_data_never_the_test(bsds_checkout, tmp_path):
    train = tmp_path / "train"
    prepare_corpus("bsds500", bsds_checkout, train, val_fraction=0.0)
    test = tmp_path / "test"
    prepare_corpus("folder", bsds_checkout / "BSDS500" / "data" / "images" / "val", test, licence="CC0", role="test")
    assert len(PhotoCorpus(test, "test")) == 1 and len(PhotoCorpus(train, "train")) == 5
    for split in ("train", "val"):
        with pytest.raises(InputError, match="untouched test split"):
            PhotoCorpus([train, test], split)
    with pytest.raises(InputError, match="a training corpus"):
        PhotoCorpus(train, "test")
    with pytest.raises(InputError, match="no val photographs"):
        PhotoCorpus(train, "val")
    # a file changed after preparation is refused by its digest
    f = json.loads((train / "manifest.json").read_text())["files"][0]["file"]
    iio.imwrite(train / f, _photo(99, 321, 481))
    with pytest.raises(InputError, match="sha256 differs"):
        PhotoCorpus(train, "train")
    with pytest.raises(InputError, match="no manifest.json"):
        PhotoCorpus(tmp_path, "train")


def test_views_are_native_scale_crops_turned_and_flipped(tmp_path):
    d = tmp_path / "src"
    d.mkdir()
    img = _photo(3, 200, 400)  # landscape: a 300-tall crop fits only turned
    iio.imwrite(d / "wide.png", img)
    prepare_corpus("folder", d, tmp_path / "c", licence="CC0", val_fraction=0.0)
    corpus = PhotoCorpus(tmp_path / "c", "train")
    ref = torch.from_numpy(img).permute(2, 0, 1).float() / 255
    # every view is one of the image's eight orientations, cropped without resampling
    orients = [ref, ref.flip(-1), ref.flip(-2), ref.flip(-1).flip(-2)]
    orients += [o.transpose(1, 2) for o in orients]
    for seed in range(6):
        v = corpus.view(64, 48, np.random.default_rng(seed))
        assert v.shape == (3, 64, 48) and v.dtype == torch.float32
        assert any(
            (o.unfold(1, 64, 1).unfold(2, 48, 1).permute(1, 2, 0, 3, 4) == v).all(-1).all(-1).all(-1).any()
            for o in orients
        )
    assert corpus.view(300, 150, np.random.default_rng(0)).shape == (3, 300, 150)  # turned
    torch.testing.assert_close(
        corpus.view(64, 64, np.random.default_rng(5)), corpus.view(64, 64, np.random.default_rng(5))
    )
    with pytest.raises(InputError, match="holds a 420 x 64 crop"):
        corpus.view(420, 64, np.random.default_rng(0))
    # the training mix with a corpus: its photographs the majority
    assert PHOTO_MIX["corpus_photo"] > 0.5
    assert natural_scene(96, np.random.default_rng(1), {"corpus_photo": 1.0}, corpus).shape == (3, 96, 96)
    with pytest.raises(InputError, match="needs a corpus"):
        natural_scene(96, np.random.default_rng(1), {"corpus_photo": 1.0})


def test_the_test_splits_samples_follow_the_protocol(tmp_path):
    d = tmp_path / "src"
    d.mkdir()
    for i in range(2):
        iio.imwrite(d / f"p{i}.png", _photo(10 + i, 300, 420))
    prepare_corpus("folder", d, tmp_path / "t", licence="CC0", role="test")
    corpus = PhotoCorpus(tmp_path / "t", "test")
    frame = SensorFrame()
    size, margin = 96, 10
    samples = photo_test_set(corpus, size, margin, 0.7, frame)
    assert [s.position for s in samples[:6]] == ["frame"] * 4 + ["centre", "corner"]
    assert [s.noise_seed for s in samples] == [TEST_NOISE0 + 1000 * k + j for k in range(2) for j in range(6)]
    full = size + 2 * margin
    for s in samples[:6]:
        # the crop lies where its sensor position lies, as if the photograph filled the frame
        cy, cx = s.offset_px
        y0 = round(cy + (frame.height - 1) / 2 - (size - 1) / 2)
        x0 = round(cx + (frame.width - 1) / 2 - (size - 1) / 2)
        py = round(y0 / (frame.height - size) * (300 - full))
        px = round(x0 / (frame.width - size) * (420 - full))
        crop = corpus[0][:, py : py + full, px : px + full]
        torch.testing.assert_close(s.scene, srgb_to_linear(crop) * 0.7)  # native scale: no resampling
        torch.testing.assert_close(
            s.target, linear_to_srgb((srgb_to_linear(crop) * 0.7).clamp(0, 1))[:, margin:-margin, margin:-margin]
        )
    corner = samples[5].scene
    torch.testing.assert_close(corner, srgb_to_linear(corpus[0][:, -full:, -full:]) * 0.7)
    # the four frame positions fall in the four quadrants
    quads = {(s.offset_px[0] > 0, s.offset_px[1] > 0) for s in samples[:4]}
    assert len(quads) == 4
    with pytest.raises(InputError, match="under the 416 x 416 crop"):
        photo_test_set(corpus, 400, 8, 0.7, frame)


def test_cli_prepares_and_lists_sources(bsds_checkout, tmp_path):
    res = CliRunner().invoke(main, ["scenes", "photos", "sources"])
    assert res.exit_code == 0 and {json.loads(x)["source"] for x in res.output.splitlines()} == set(SOURCES)
    out = tmp_path / "corpus"
    res = CliRunner().invoke(
        main, ["scenes", "photos", "prepare", "bsds500", "--from", str(bsds_checkout), "--out", str(out), "--quiet"]
    )
    assert res.exit_code == 0, res.output
    line = json.loads(res.output)
    assert line["counts"]["train"] + line["counts"]["val"] == 5 and line["role"] == "train"
    res = CliRunner().invoke(
        main, ["scenes", "photos", "prepare", "kodak24", "--from", str(bsds_checkout), "--out", str(tmp_path / "k")]
    )
    assert res.exit_code == 1 and res.output.count("\n") == 1 and "has no folder testsets/Kodak24" in res.output


@pytest.mark.slow
def test_isp_pretraining_on_photographs_records_the_corpus(bsds_checkout, tmp_path):
    import dataclasses

    from optix_e2e.camera_design.isp_pretraining import PretrainConfig, pretrain

    prepare_corpus("bsds500", bsds_checkout, tmp_path / "c", val_fraction=0.5)
    corpus = PhotoCorpus(tmp_path / "c", "train")
    cfg = PretrainConfig(
        steps=2,
        batch=2,
        crop=32,
        pool=4,
        pool_steps=2,
        width=8,
        depth=2,
        val_size=2,
        val_every=2,
        threads=1,
        photos=(str(tmp_path / "c"),),
        lpips_weight=0.5,
    )
    meta = pretrain(cfg, tmp_path / "run", progress=False, log=lambda m: None)
    assert meta["photos"]["digest"] == corpus.digest and meta["validation"]["split"] == "val"
    assert meta["steps"] == 2 and np.isfinite(meta["curve"][-1]["psnr_db"])
    # a resume on other photographs is refused: the corpus is part of the run's settings
    images = bsds_checkout / "BSDS500" / "data" / "images"
    prepare_corpus("folder", images, tmp_path / "c2", licence="CC0", val_fraction=0.5)
    with pytest.raises(InputError, match="other settings"):
        pretrain(dataclasses.replace(cfg, steps=4, photos=(str(tmp_path / "c2"),)), tmp_path / "run", progress=False)


def test_design_runs_train_on_a_corpus_when_given_one(bsds_checkout, tmp_path):
    from optix_e2e.camera_design.config import make_config
    from optix_e2e.tasks import training_batch

    prepare_corpus("bsds500", bsds_checkout, tmp_path / "c", val_fraction=0.0)
    corpus = PhotoCorpus(tmp_path / "c", "train")
    args = (3, 5, 4, 32, 8, (0.35, 1.0))
    plain, with_photos = training_batch(*args), training_batch(*args, corpus=corpus)
    again = training_batch(*args, corpus=corpus)
    torch.testing.assert_close(with_photos.scene, again.scene)  # a function of (seed, step) alone
    assert not torch.equal(plain.scene, with_photos.scene)
    cfg = make_config("smoke", task="iq-software", photos=str(tmp_path / "c"))
    assert cfg.photos == str(tmp_path / "c")
    with pytest.raises(InputError, match="photos: no such folder"):
        make_config("smoke", photos=str(tmp_path / "missing"))


@pytest.mark.slow
def test_a_smoke_design_run_trains_on_photographs(bsds_checkout, tmp_path, optix, smoke_design):
    prepare_corpus("bsds500", bsds_checkout, tmp_path / "c", val_fraction=0.0)
    r = optix(*smoke_design("iq-software", tmp_path / "run", "--photos", tmp_path / "c"))
    assert r.returncode == 0, r.stdout + r.stderr
    inputs = json.loads((tmp_path / "run" / "inputs.json").read_text())
    assert inputs["photos"]["fingerprint"].startswith("folder-sha256:")
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["photos"] == str(tmp_path / "c")
    r = optix(*smoke_design("detection", tmp_path / "det", "--photos", tmp_path / "c"))
    assert r.returncode == 1 and "photos is for the image-quality tasks" in r.stderr
