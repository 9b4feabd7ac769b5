"""The sharded PSF dataset (optix_e2e.dataset, ``optix dataset``): layout, resume after a
kill, determinism, failure records, corruption detection, multi-process merging, and the
torch Dataset."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from optix_e2e.cli.dataset import dataset
from optix_e2e.dataset import DatasetError, DatasetSettings, generate, verify
from optix_e2e.dataset.merge import merge
from optix_e2e.dataset.torch_dataset import PsfDataset
from optix_e2e.lens import Lens

# small and quick: 3 fields, a 32 um window, 32 pupil samples
SMALL = ["--fields", "3", "--window-um", "32", "--pupil-samples", "32", "--shard-size", "3"]
SMALL_SETTINGS = DatasetSettings(n_fields=3, window_um=32.0, pupil_samples=32, shard_size=3)


def _cli(*args, env=None):
    """Run ``optix dataset ...`` in a subprocess (so it can be killed)."""
    return subprocess.Popen(
        [sys.executable, "-m", "optix_e2e", "dataset", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )


def sensor_binning(size: int, pitch_um: float, s_size: int, s_pitch_um: float) -> np.ndarray:
    """(s_size, size) weights, independently of the engine: the overlap of each fine pixel
    (a box of one pitch around its centre) with each sensor pixel, as a fraction of the
    fine pixel; both grids centred on pixel size // 2."""
    x = (np.arange(size) - size // 2) * pitch_um
    c = (np.arange(s_size) - s_size // 2) * s_pitch_um
    ov = np.minimum(x[None, :] + pitch_um / 2, c[:, None] + s_pitch_um / 2) - np.maximum(
        x[None, :] - pitch_um / 2, c[:, None] - s_pitch_um / 2
    )
    return np.clip(ov, 0.0, None) / pitch_um


def _arrays(root: Path) -> dict:
    out = {}
    for d in sorted((root / "shards").iterdir()):
        for f in sorted(d.glob("*.npy")):
            out[f"{d.name}/{f.name}"] = f.read_bytes()
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted run: 8 designs in shards of 3."""
    root = tmp_path_factory.mktemp("ref") / "ds"
    rep = generate("paper-triplet", 8, 11, root, SMALL_SETTINGS, progress=False)
    assert rep.shards_written == [0, 1, 2] and rep.n_ok + rep.n_failed == 8
    return root


def test_layout_shapes_and_physics(reference):
    man = json.loads((reference / "manifest.json").read_text())
    assert man["n_shards"] == 3 and man["psf_size"] == 32 and man["sensor_size"] == 5
    assert man["fields_deg"] == pytest.approx([0.0, 7.45, 14.9])
    assert man["channels"] == [[[650.0, 1.0]], [[550.0, 1.0]], [[470.0, 1.0]]]
    assert len(man["param_mean"]) == len(man["space"]["parameters"]) == 19
    rep = verify(reference)
    assert rep["ok"] and rep["n_designs"] + rep["n_failed"] == 8
    psf = np.load(reference / "shards" / "00000" / "psf.npy")
    sens = np.load(reference / "shards" / "00000" / "psf_sensor.npy")
    ri = np.load(reference / "shards" / "00000" / "relative_illumination.npy")
    np.testing.assert_allclose(psf.sum(axis=(-1, -2)), 1.0, atol=1e-5)  # unit sum per channel
    assert np.all(ri[:, 0] == 1.0) and np.all(ri > 0)  # relative to the axis
    # the sensor version integrates the fine PSF over 5.86 um pixels: its energy is the fine
    # PSF's energy inside the 5 x 5 pixel block (29.3 um of the 32 um window)
    w = sensor_binning(32, 1.0, 5, 5.86)
    np.testing.assert_allclose(w.sum(axis=0)[2:30], 1.0, atol=1e-12)
    np.testing.assert_allclose(
        sens.sum(axis=(-1, -2)), np.einsum("mkcyx,x,y->mkc", psf.astype(float), w.sum(axis=0), w.sum(axis=0)), rtol=1e-5
    )
    # pixel by pixel: the engine bins the double-precision PSF; the float32 one binned here
    # agrees to float32 rounding
    np.testing.assert_allclose(sens, np.einsum("iy,mkcyx,jx->mkcij", w, psf.astype(float), w), rtol=2e-6, atol=1e-9)


def test_designs_match_the_sampler_and_psfs_match_the_engine(reference):
    from optix_e2e import _engine
    from optix_e2e.lens.apertures import engine_base
    from optix_e2e.lens_design.space import load_space

    space, base = load_space("paper-triplet")
    x = np.load(reference / "shards" / "00000" / "params.npy")[0]
    d = space.apply(engine_base(base, "auto"), x)
    d["surfaces"][-1]["thickness"] = float(np.load(reference / "shards" / "00000" / "image_distance.npy")[0])
    psf, ri, diags = _engine.psf_rgb(
        json.dumps(d), 14.9, [[(650.0, 1.0)], [(550.0, 1.0)], [(470.0, 1.0)]], "auto", 1.0, 32, 32
    )  # the dataset default
    stored = np.load(reference / "shards" / "00000" / "psf.npy")[0, 2]
    np.testing.assert_allclose(stored, psf, rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.load(reference / "shards" / "00000" / "relative_illumination.npy")[0, 2], ri)
    # the energy each PSF keeps in its 32 um window, and the engine's warnings about it
    energy = np.load(reference / "shards" / "00000" / "energy_in_window.npy")
    np.testing.assert_allclose(energy[0, 2], [w["energy_in_window"] for w in diags["per_wavelength"]], rtol=1e-6)
    assert np.all((energy > 0.1) & (energy <= 1.0 + 1e-6))  # a 32 um window cuts off the edge PSFs
    meta = json.loads((reference / "shards" / "00000" / "shard.json").read_text())
    lost = [f"{100 * (1 - e):.1f}% of the transmitted energy falls outside" for e in energy[0, 2] if e < 0.99]
    assert lost and all(any(t in w for w in meta["warnings"]["0"]) for t in lost)


def test_killed_and_resumed_equals_uninterrupted(tmp_path):
    """kill -9 as soon as the first shard is in place, a stale half-written shard of a dead
    process beside it, then the same command again: byte-identical to an uninterrupted run."""
    n, settings = 60, DatasetSettings(n_fields=3, window_um=32.0, pupil_samples=32, shard_size=3)
    whole = tmp_path / "whole"
    generate("paper-triplet", n, 11, whole, settings, progress=False)
    root = tmp_path / "ds"
    args = ["paper-triplet", "-n", n, "--seed", 11, "--out", root, *SMALL]
    p = _cli(*args)
    deadline = time.time() + 120
    while not (root / "shards" / "00000").is_dir() and time.time() < deadline and p.poll() is None:
        time.sleep(0.005)
    p.send_signal(signal.SIGKILL)
    p.wait()
    done = sorted(d.name for d in (root / "shards").iterdir() if not d.name.startswith("."))
    assert done and len(done) < n // 3, f"the kill did not land mid-run: {done}"
    stale = root / "shards" / ".00019.tmp-999999999"
    stale.mkdir(parents=True, exist_ok=True)
    (stale / "psf.npy").write_bytes(b"garbage")
    q = _cli(*args)
    out, err = q.communicate(timeout=300)
    assert q.returncode == 0, err.decode()
    rep = json.loads(out.decode().strip().splitlines()[-1])
    assert rep["shards_skipped"] == [int(d) for d in done]
    assert rep["shards_written"] == [k for k in range(n // 3) if f"{k:05d}" not in done]
    assert not stale.exists()
    assert _arrays(root) == _arrays(whole)  # byte-identical arrays
    assert verify(root)["digest"] == verify(whole)["digest"]
    # a finished dataset: the same command does nothing
    rep2 = generate("paper-triplet", n, 11, root, settings, progress=False)
    assert rep2.shards_written == [] and rep2.shards_skipped == list(range(n // 3))


def test_direct_io_writes_the_same_data(reference, tmp_path, monkeypatch):
    """With every aligned array written by direct I/O (the size threshold lowered so these
    small shards take that path, a sub-block tail included): the same dataset digest as the
    buffered reference, and numpy reads the 4 KiB-header files."""
    from optix_e2e.dataset import layout

    monkeypatch.setattr(layout, "DIRECT_MIN_BYTES", 0)
    root = tmp_path / "direct"
    generate("paper-triplet", 8, 11, root, SMALL_SETTINGS, progress=False)
    for name in ("psf", "psf_sensor"):
        p = root / "shards" / "00000" / f"{name}.npy"
        assert 10 + int.from_bytes(p.read_bytes()[8:10], "little") == layout.ALIGN
        np.testing.assert_array_equal(np.load(p), np.load(reference / "shards" / "00000" / f"{name}.npy"))
    rep, ref = verify(root), verify(reference)
    assert rep["ok"] and rep["digest"] == ref["digest"]


def test_same_arrays_whatever_the_thread_count(reference, tmp_path):
    env = dict(os.environ, RAYON_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    p = _cli("paper-triplet", "-n", 8, "--seed", 11, "--out", tmp_path / "one", *SMALL, env=env)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err.decode()
    assert _arrays(tmp_path / "one") == _arrays(reference)


def test_other_arguments_refuse_the_directory(reference, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    with pytest.raises(
        DatasetError, match=r"manifest.json: this directory holds a different dataset \(differs in: seed\)"
    ):
        generate("paper-triplet", 8, 12, root, SMALL_SETTINGS, progress=False)


def test_a_space_read_from_elsewhere_resumes_and_a_changed_one_is_refused(reference, tmp_path):
    """Where the space was read from (its TOML's path: another install's bundled copy, a copy
    of the file) is not what the data depends on: the dataset resumes. A changed range is."""
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    mpath = root / "manifest.json"
    man = json.loads(mpath.read_text())
    man["space"]["source"] = "/another/venv/optix_e2e/bundled/spaces/paper-triplet.toml"
    mpath.write_text(json.dumps(man))
    rep = generate("paper-triplet", 8, 11, root, SMALL_SETTINGS, progress=False)
    assert rep.shards_written == [] and len(rep.shards_skipped) == man["n_shards"]
    man["space"]["parameters"][0]["max"] += 1.0
    mpath.write_text(json.dumps(man))
    with pytest.raises(DatasetError, match=r"a different dataset \(differs in: space\)"):
        generate("paper-triplet", 8, 11, root, SMALL_SETTINGS, progress=False)


# A design of paper-triplet-detect-wide (its dataset of 2026-11-28, design 48) whose least-RMS
# plane over the fields lies inside its last surface: the outer fields' aberrations pull it
# there, though its paraxial focus is 16.7 mm behind
FOCUS_INSIDE = {
    "s_1_radius": 25.51714382, "s_1_conic": 0.1935969225, "s_2_radius": -26.95442499, "l_12": 8.157901782,
    "l_2STO": 0.7741728076, "l_STO3": 5.504150279, "s_6_radius": 79.17561969, "s_6_conic": 0.04272611014,
    "s_7_radius": -7.734217466, "s_1_2nd": 8.712138201e-06, "s_1_4th": -4.791839226e-05,
    "s_1_6th": -7.113181809e-07, "s_1_8th": 7.654656152e-09, "s_1_10th": 7.904009161e-11,
    "s_6_2nd": 0.0004856321904, "s_6_4th": -0.0006700533432, "s_6_6th": 9.445920416e-06,
    "s_6_8th": -6.064830671e-07, "s_6_10th": -3.69162529e-10, "s_1_thickness": 7.595919563,
    "s_6_thickness": 2.093591766, "f_number": 3.514639631,
}  # fmt: skip


def test_a_focus_short_of_the_back_focus_limit_images_at_the_limit(tmp_path):
    """focus_within "bfd": a design whose best focus falls short of the space's min_bfd (here
    inside the last surface) is imaged at the limit, its shard's warnings say so, its PSFs are
    finite, and the limit is the best plane allowed. "none", the datasets' rule before, fails
    it naming the focus."""
    from optix_e2e.dataset.manifest import refocused_designs
    from optix_e2e.lens_design.focus import best_focus_shift
    from optix_e2e.surrogate.ground_truth import exact_arrays

    s = DatasetSettings(n_fields=3, window_um=32.0, pupil_samples=32, shard_size=1, focus_within="bfd")
    generate("paper-triplet-detect-wide", 1, 0, tmp_path / "ds", s, progress=False)
    man = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert man["settings"]["focus_within"] == "bfd" and man["space"]["constraints"]["min_bfd"] == 10.0
    v = np.array([[FOCUS_INSIDE[p["name"]] for p in man["space"]["parameters"]]])
    arrays, meta = exact_arrays(man, v)
    assert meta["n_failed"] == 0 and arrays["image_distance"].tolist() == [10.0]
    assert "inside the last surface" in meta["warnings"]["0"][0] and "at the limit, 10 mm" in meta["warnings"]["0"][0]
    assert np.isfinite(arrays["psf"]).all() and np.isfinite(arrays["energy_in_window"]).all()
    # the best plane allowed: from the limit, the free best focus (the mean square spot over
    # the fields, a quadratic in the plane's position) lies nearer still, where the plane cannot go
    d = refocused_designs(man, v, [10.0])[0]
    wl = sorted({w for c in man["channels"] for w, _ in c})
    shift = best_focus_shift(json.dumps(d), man["fields_deg"], wl, rings=4)
    assert shift == pytest.approx(-13.77, abs=0.05)
    # and a design run's final check calls that plane refocused, at the limit
    from optix_e2e.camera_design.outputs import focus_check

    check = focus_check(man, d)
    assert check["refocused"] and check["at_back_focus_limit"] and check["focus_shift_um"] < -13_000
    assert not focus_check({**man, "settings": {**man["settings"], "focus_within": "none"}}, d)["refocused"]
    arrays, meta = exact_arrays({**man, "settings": {**man["settings"], "focus_within": "none"}}, v)
    assert meta["n_failed"] == 1 and meta["failures"][0]["reason"].startswith("focus: the best focus lies 3.")
    assert "inside the last surface" in meta["failures"][0]["reason"]


def test_the_cli_makes_new_datasets_within_the_back_focus_limit_and_resumes_old_ones_as_made(tmp_path):
    root = tmp_path / "ds"
    args = ("generate", "paper-triplet", "-n", 2, "--seed", 3, "--out", root, *SMALL)
    p = _cli(*args)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err.decode()
    man = json.loads((root / "manifest.json").read_text())
    assert man["settings"]["focus_within"] == "bfd"
    # a dataset made before the setting (its manifest has no key): the same command resumes it
    # on its own rule, and only an explicit other rule is refused
    del man["settings"]["focus_within"]
    (root / "manifest.json").write_text(json.dumps(man))
    p = _cli(*args)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err.decode()
    p = _cli(*args, "--focus-within", "bfd")
    _, err = p.communicate(timeout=300)
    assert p.returncode != 0 and b"differs in: settings (focus_within: 'none' there, 'bfd' asked)" in err


def test_a_damaged_manifest_is_refused_in_one_error_and_left_as_it_is(tmp_path):
    for text, words in (
        ("[1]", "not a dataset manifest"),
        ('{"settings": "x"}', "a different dataset"),
        ('{"settings": {"focus_within": "bfd"}}', "a different dataset"),
    ):
        root = tmp_path / f"ds{len(text)}"
        root.mkdir()
        (root / "manifest.json").write_text(text)
        with pytest.raises(DatasetError, match=words):
            generate("paper-triplet", 2, 0, root, SMALL_SETTINGS, progress=False)
        assert (root / "manifest.json").read_text() == text and [p.name for p in root.iterdir()] == ["manifest.json"]


def test_corruption_is_detected(reference, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    f = root / "shards" / "00001" / "psf.npy"
    b = bytearray(f.read_bytes())
    b[-5] ^= 0xFF
    f.write_bytes(bytes(b))
    rep = verify(root)
    assert not rep["ok"] and len(rep["problems"]) == 1
    assert "00001/psf.npy: checksum mismatch" in rep["problems"][0]
    ds = PsfDataset(root)
    ds[0]  # shard 0 is fine
    with pytest.raises(DatasetError, match=r"00001/psf.npy: checksum mismatch"):
        for i in range(len(ds)):
            ds[i]
    r = CliRunner().invoke(dataset, ["verify", str(root)])
    assert r.exit_code == 1 and json.loads(r.stdout.splitlines()[0])["ok"] is False
    shutil.rmtree(root / "shards" / "00002")
    rep = verify(root)
    assert rep["missing_shards"] == [2]


def test_engine_failures_are_recorded_not_written(tmp_path):
    """Designs the sampler would never produce, put through the shard writer directly: one
    whose surfaces cross and one whose surface is too small for its beam (the engine would
    trace both; the generator checks), and, with the base lens's apertures kept, one
    whose edge-field chief ray the engine finds clipped.  Each lands in the shard's failure
    list with its reason; the good designs are written."""
    from optix_e2e.dataset.manifest import prepare
    from optix_e2e.dataset.shards import compute_shard, write_shard
    from optix_e2e.lens_design.space import load_space

    (tmp_path / "lens.json").write_text(json.dumps(Lens.load("cooke-f50").data))
    space_file = tmp_path / "space.toml"
    space_file.write_text(
        'lens = "lens.json"\n'
        '[[parameter]]\nname = "s_2_thickness"\nkind = "air_gap"\nsurface = 2\nmin = 0.01\nmax = 8.0\n'
        '[[parameter]]\nname = "s_5_radius"\nkind = "radius"\nsurface = 5\nmin = 5.0\nmax = 100.0\n'
        '[[parameter]]\nname = "s_6_radius"\nkind = "radius"\nsurface = 6\nmin = -30.0\nmax = -4.0\n'
    )
    space, base = load_space(space_file)
    s = DatasetSettings(n_fields=2, window_um=24, pupil_samples=16, shard_size=3)
    root = tmp_path / "ds"
    man, _ = prepare(root, space, base, 3, 0, s)
    designs = np.array(
        [
            [6.00755, 79.6836, -18.39533],  # the nominal
            [0.05, 79.6836, -18.39533],  # lens 1 and lens 2 cross
            [6.00755, 6.0, -18.39533],
        ]
    )  # R5 = 6 mm inside a 6.9 mm aperture
    arrays, meta = compute_shard(0, man, designs, space, base)
    assert write_shard(root, 0, arrays, meta)
    reasons = {f["design"]: f["reason"] for f in meta["failures"]}
    assert reasons[1].startswith("surfaces_cross: ") and "surfaces 2 and 3 cross" in reasons[1], reasons[1]
    # R5 = 6 mm in a 6.2 mm beam (each design at its own footprint, lens_design.constraints)
    assert reasons[2].startswith("surfaces_cross: ") and "surfaces 5 and 6 cross" in reasons[2], reasons[2]
    assert meta["failures"][1]["params"] == {"s_2_thickness": 6.00755, "s_5_radius": 6.0, "s_6_radius": -18.39533}
    assert np.load(root / "shards" / "00000" / "design.npy").tolist() == [0]
    # these designs replace the sampled ones: designs.csv and its checksum must say so
    from optix_e2e.dataset.layout import sha256_file
    from optix_e2e.io import write_json_atomic
    from optix_e2e.lens_design.sampling import write_designs_csv

    write_designs_csv(root / "designs.csv", space.names, designs)
    write_json_atomic(root / "manifest.json", {**man, "designs_csv_sha256": sha256_file(root / "designs.csv")})
    rep = verify(root)
    assert rep["ok"] and (rep["n_designs"], rep["n_failed"]) == (1, 2)
    # the engine's own refusal: with the base lens's clear apertures kept ("fixed") and
    # surface 1 cut to 3 mm, the 20 deg chief ray is clipped there
    data = Lens.load("cooke-f50").data
    data["surfaces"][0]["semi_diameter"] = 3.0
    (tmp_path / "lens.json").write_text(json.dumps(data))
    space, base = load_space(space_file)
    s = DatasetSettings(n_fields=2, window_um=24, pupil_samples=16, shard_size=3, apertures="fixed")
    man, _ = prepare(tmp_path / "ds2", space, base, 3, 0, s)
    _, meta = compute_shard(0, man, designs[[0, 0, 0]], space, base)
    assert [f["reason"] for f in meta["failures"]] == [
        "field 20 deg: trace: chief ray at 20 deg, 650.0 nm: Clipped at surface 1"
    ] * 3


def test_disjoint_shard_ranges_merge_to_the_same_data(reference, tmp_path):
    """Two processes on disjoint shard ranges into separate directories, then merged; and
    two ranges into one shared directory."""
    a, b = tmp_path / "a", tmp_path / "b"
    generate("paper-triplet", 8, 11, a, SMALL_SETTINGS, shards="0:2", progress=False)
    generate("paper-triplet", 8, 11, b, SMALL_SETTINGS, shards="2:", progress=False)
    assert not verify(a)["ok"] and verify(a)["missing_shards"] == [2]
    r = CliRunner().invoke(dataset, ["merge", str(tmp_path / "m"), str(a), str(b)])
    assert r.exit_code == 0, r.output
    assert verify(tmp_path / "m")["digest"] == verify(reference)["digest"]
    shared = tmp_path / "shared"
    generate("paper-triplet", 8, 11, shared, SMALL_SETTINGS, shards="1", progress=False)
    generate("paper-triplet", 8, 11, shared, SMALL_SETTINGS, shards="0:1", progress=False)
    generate("paper-triplet", 8, 11, shared, SMALL_SETTINGS, shards="2:3", progress=False)
    assert _arrays(shared) == _arrays(reference)
    other = tmp_path / "other"
    generate("paper-triplet", 8, 12, other, SMALL_SETTINGS, shards="0", progress=False)
    with pytest.raises(DatasetError, match=r"other/manifest.json: a different dataset .*differs in: .*seed"):
        merge(tmp_path / "m2", [a, other])
    # merge writes only into its own folder: not over optix sample's designs.csv, nor a design run
    for name, text in (("designs.csv", "design,s_1_radius\n0,30.0\n"), ("config.json", "{}")):
        folder = tmp_path / f"not-ours-{name}"
        folder.mkdir()
        (folder / name).write_text(text)
        r = CliRunner().invoke(dataset, ["merge", str(folder), str(a), str(b)])
        assert r.exit_code == 1 and "choose another --out" in r.output, r.output
        assert [p.name for p in folder.iterdir()] == [name] and (folder / name).read_text() == text
    again = CliRunner().invoke(dataset, ["merge", str(tmp_path / "m"), str(a), str(b)])  # its own: resumes
    assert again.exit_code == 0, again.output


def test_torch_dataset(reference):
    ds = PsfDataset(reference)
    man = ds.manifest
    n_ok = verify(reference)["n_designs"]
    assert len(ds) == n_ok * 3 and ds.n_designs == n_ok
    item = ds[4]  # design 1, field 1
    assert item["psf"].shape == (3, 32, 32) and item["psf"].dtype == torch.float32
    assert item["field"].item() == pytest.approx(0.5) and item["field_deg"] == pytest.approx(7.45)
    torch.testing.assert_close(item["psf"].sum(dim=(1, 2)), torch.ones(3), atol=1e-5, rtol=0)
    # parameters normalized by the manifest's mean and std over the designs
    raw = np.load(reference / "shards" / "00000" / "params.npy")[1]
    expect = (raw - np.array(man["param_mean"])) / np.array(man["param_std"])
    np.testing.assert_allclose(item["params"].numpy(), expect, rtol=1e-6, atol=1e-6)
    all_params = np.array([ds[i * 3]["params"].numpy() for i in range(ds.n_designs)], float)
    if n_ok == 8:  # mean/std are over all sampled designs
        np.testing.assert_allclose(all_params.mean(axis=0), 0.0, atol=1e-5)
    # a held-out subset by design index, and the sensor-pitch PSFs
    held = PsfDataset(reference, psf="psf_sensor", designs=[int(item["design"])])
    assert len(held) == 3 and held[1]["psf"].shape == (3, 5, 5) and held[1]["design"] == item["design"]
    loader = torch.utils.data.DataLoader(
        ds, batch_size=5, num_workers=2, shuffle=True, generator=torch.Generator().manual_seed(0)
    )
    batch = next(iter(loader))
    assert batch["psf"].shape == (5, 3, 32, 32) and batch["params"].shape == (5, 19)


def test_cli_errors(tmp_path):
    r = CliRunner().invoke(dataset, ["no-such-space", "-n", "2", "--out", str(tmp_path / "x")])
    assert r.exit_code == 1 and "neither a space file nor a bundled lens" in r.output
    r = CliRunner().invoke(dataset, ["paper-triplet", "-n", "2", "--out", str(tmp_path / "x"), "--shards", "5:9"])
    assert r.exit_code == 1 and "--shards '5:9': the dataset has shards 0..0" in r.output
    r = CliRunner().invoke(dataset, ["verify", str(tmp_path)])
    assert r.exit_code == 1 and "manifest.json: missing manifest" in r.output


@pytest.mark.parametrize("shape, aligned", [((3, 512, 700), True), ((3, 512, 700), False), ((5,), True)])
def test_save_npy_direct_and_buffered_files_read_back(tmp_path, shape, aligned):
    """save_npy: large aligned arrays go through direct I/O (header padded to one 4 KiB block,
    the body unbuffered, a tail under one block buffered); others through the page cache.
    Every file loads back equal and its returned CRC is the file's."""
    from optix_e2e.dataset.layout import ALIGN, aligned_empty, crc32_file, save_npy

    rng = np.random.default_rng(0)
    a = aligned_empty(shape, np.float32) if aligned else np.empty(np.prod(shape) + 1, np.float32)[1:].reshape(shape)
    a[...] = rng.random(shape, dtype=np.float32)
    assert (a.ctypes.data % ALIGN == 0) == aligned
    p = tmp_path / "a.npy"
    crc = save_npy(p, a)
    assert crc == crc32_file(p)
    np.testing.assert_array_equal(np.load(p), a)
    np.testing.assert_array_equal(np.load(p, mmap_mode="r"), a)
    header = 10 + int.from_bytes(p.read_bytes()[8:10], "little")
    assert header == (ALIGN if aligned and a.nbytes >= 1 << 20 else 128)
    assert p.stat().st_size == header + a.nbytes
