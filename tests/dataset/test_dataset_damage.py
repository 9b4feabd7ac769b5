"""Damaged datasets: a re-run redoes a damaged shard, a damaged manifest
key or a changed designs.csv gives one clear error in verify and PsfDataset."""

from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from optix_e2e.cli import main
from optix_e2e.dataset import DatasetSettings, generate
from optix_e2e.dataset.layout import DatasetError
from optix_e2e.dataset.torch_dataset import PsfDataset
from optix_e2e.dataset.verify import verify

SETTINGS = DatasetSettings(n_fields=2, window_um=24, pupil_samples=16, shard_size=3)
N, SEED = 7, 5


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    out = tmp_path_factory.mktemp("damage") / "data"
    generate("paper-triplet", N, SEED, out, SETTINGS, progress=False)
    return out


@pytest.fixture
def data(pristine, tmp_path):
    """A fresh copy of the small dataset for each test to damage."""
    out = tmp_path / "data"
    shutil.copytree(pristine, out)
    return out


def _verify_cli(root):
    return CliRunner().invoke(main, ["dataset", "verify", str(root)])


@pytest.mark.parametrize(
    "damage",
    [
        "shard.json",
        "psf.npy",
        "energy_in_window.npy",
        "truncate psf.npy",
        "flip a byte of psf_sensor.npy",
        "empty shard.json",
    ],
)
def test_rerun_redoes_a_damaged_shard(data, pristine, damage):
    shard = data / "shards" / "00001"
    if damage.startswith("truncate"):
        p = shard / damage.split()[1]
        p.write_bytes(p.read_bytes()[:-100])
    elif damage.startswith("flip"):
        p = shard / damage.split()[-1]
        b = bytearray(p.read_bytes())
        b[-5] ^= 0xFF
        p.write_bytes(bytes(b))
    elif damage.startswith("empty"):
        (shard / "shard.json").write_text("")
    else:
        (shard / damage).unlink()
    assert not verify(data)["ok"]
    logs = []
    rep = generate("paper-triplet", N, SEED, data, SETTINGS, progress=False, log=logs.append)
    assert rep.shards_written == [1] and rep.shards_skipped == [0, 2], rep
    assert any("shard 1" in m and "redo" in m for m in logs), logs
    after, before = verify(data), verify(pristine)
    assert after["ok"] and after["digest"] == before["digest"], after["problems"]
    # the damaged files are kept aside, not deleted
    assert any(p.name.startswith(".00001.damaged") for p in (data / "shards").iterdir())


@pytest.mark.parametrize("name", ["psf", "psf_sensor"])
def test_a_shard_of_all_zero_psfs_with_matching_checksums_fails_verify(data, name):
    """PSFs zeroed and the shard's checksum forged to match (what a bad copy or a hand edit
    leaves): verify names the file and the reason, every PSF channel has light."""
    import numpy as np

    from optix_e2e.dataset.layout import crc32_file

    shard = data / "shards" / "00001"
    p = shard / f"{name}.npy"
    np.save(p, np.zeros_like(np.load(p)))
    meta = json.loads((shard / "shard.json").read_text())
    meta["files"][name]["crc32"] = crc32_file(p)
    (shard / "shard.json").write_text(json.dumps(meta))
    rep = verify(data)
    assert not rep["ok"]
    assert any(f"{name}.npy" in m and ("not 1" in m or "to nothing" in m) for m in rep["problems"]), rep["problems"]
    res = _verify_cli(data)
    assert res.exit_code != 0 and "Traceback" not in res.output


@pytest.mark.parametrize(
    "key, value",
    [
        ("n_shards", None),
        ("fields_deg", "x"),
        ("settings", {"shard_size": "3"}),
        ("param_mean", [1.0]),
        ("channels", 7),
        ("psf_size", -1),
        ("space", {"parameters": [{"min": 0}]}),
        ("n_designs", 1e400),
    ],
)
def test_damaged_manifest_key_is_one_clear_error(data, key, value):
    mpath = data / "manifest.json"
    man = json.loads(mpath.read_text())
    if value is None:
        del man[key]
    else:
        man[key] = value
    mpath.write_text(json.dumps(man).replace("Infinity", "1e400"))
    top = key.split(".")[0]
    for call in (lambda: verify(data), lambda: PsfDataset(data)):
        with pytest.raises(DatasetError) as err:
            call()
        assert str(mpath) in str(err.value) and top in str(err.value), str(err.value)
    res = _verify_cli(data)
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    assert [line for line in res.output.splitlines() if line.startswith("Error:")], res.output


def test_changed_designs_csv_fails_verify(data):
    dpath = data / "designs.csv"
    lines = dpath.read_text().splitlines()
    cells = lines[2].split(",")
    cells[1] = repr(float(cells[1]) * 1.01)
    lines[2] = ",".join(cells)
    dpath.write_text("\n".join(lines) + "\n")
    rep = verify(data)
    assert not rep["ok"] and any("designs.csv" in p for p in rep["problems"]), rep["problems"]
    res = _verify_cli(data)
    assert res.exit_code == 1 and "designs.csv" in res.output


def test_designs_csv_checked_against_the_shards_when_the_manifest_has_no_checksum(data):
    """A manifest without designs_csv_sha256: verify says it cannot check the file's checksum,
    and still compares designs.csv with the parameters stored in the shards."""
    mpath = data / "manifest.json"
    man = json.loads(mpath.read_text())
    del man["designs_csv_sha256"]
    mpath.write_text(json.dumps(man))
    rep = verify(data)
    assert rep["ok"] and any("designs_csv_sha256" in n for n in rep["notes"]), rep
    dpath = data / "designs.csv"
    text = dpath.read_text().splitlines()
    cells = text[1].split(",")
    cells[-1] = repr(float(cells[-1]) + 1e-9)
    text[1] = ",".join(cells)
    dpath.write_text("\n".join(text) + "\n")
    rep = verify(data)
    assert not rep["ok"] and any("designs.csv" in p and "design 0" in p for p in rep["problems"]), rep


def test_deleted_designs_csv_fails_verify(data):
    (data / "designs.csv").unlink()
    rep = verify(data)
    assert not rep["ok"] and any("designs.csv" in p for p in rep["problems"])


def test_resume_without_manifest_checksum_checks_designs_against_the_seed(data):
    mpath = data / "manifest.json"
    man = json.loads(mpath.read_text())
    del man["designs_csv_sha256"]
    mpath.write_text(json.dumps(man))
    shutil.rmtree(data / "shards" / "00002")
    logs = []
    rep = generate("paper-triplet", N, SEED, data, SETTINGS, progress=False, log=logs.append)
    assert rep.shards_written == [2] and any("designs_csv_sha256" in m for m in logs)
    dpath = data / "designs.csv"
    lines = dpath.read_text().splitlines()
    lines[-1] = lines[-1].rsplit(",", 1)[0] + ",1.0"
    dpath.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="not the designs of seed"):
        generate("paper-triplet", N, SEED, data, SETTINGS, progress=False)
