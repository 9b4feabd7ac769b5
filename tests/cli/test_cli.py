"""Smoke tests of the ``optix`` command line (click's CliRunner and a real subprocess)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from optix_e2e.cli import main


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_help_lists_subcommands():
    r = run("--help")
    assert r.exit_code == 0
    for cmd in ("lens", "psf", "demo"):
        assert cmd in r.output


def test_lens_info_json_keys():
    r = run("lens", "info", "cooke-f50", "--json")
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    for key in ("efl_mm", "bfl_mm", "f_number", "epd_mm", "total_track_mm"):
        assert isinstance(info[key], float), key
    assert info["efl_mm"] == pytest.approx(50.0, rel=1e-3)
    assert [f["field_deg"] for f in info["fields"]] == [0.0, 14.0, 20.0]
    for f in info["fields"]:
        assert f["rms_spot_um"] > 0 and 0 < f["relative_illumination"] <= 1.5


def test_lens_info_table():
    r = run("lens", "info", "cooke-f50", "--aiming", "real")
    assert r.exit_code == 0, r.output
    assert "EFL" in r.output and "RMS spot" in r.output


def test_psf_writes_npy_and_one_json_line(tmp_path):
    out, png = tmp_path / "psf.npy", tmp_path / "psf.png"
    r = run(
        "psf",
        "cooke-f50",
        "--field-deg",
        14,
        "--wavelength-nm",
        550,
        "--method",
        "fft",
        "--pixel-um",
        1.0,
        "--size",
        32,
        "--out",
        out,
        "--png",
        png,
    )
    assert r.exit_code == 0, r.output
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 1
    d = json.loads(lines[0])
    assert d["method"] == "fft" and 0 < d["strehl"] <= 1 and d["time_s"] >= 0
    assert isinstance(d["warnings"], list)
    a = np.load(out)
    assert a.shape == (32, 32) and np.all(np.isfinite(a)) and 0 < a.sum() <= 1 + 1e-9
    assert png.stat().st_size > 1000


def test_psf_refuses_an_out_that_is_not_npy(tmp_path):
    """numpy appends .npy to any other name: ``--out x.png`` wrote x.png.npy and reported x.png.
    Now one line before any work, naming --png for a picture; nothing written."""
    r = run("psf", "cooke-f50", "--size", 16, "--out", tmp_path / "x.png")
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert "--out" in r.output and ".npy" in r.output and "--png" in r.output
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("method", ["geometric", "huygens"])
def test_psf_other_methods(tmp_path, method):
    out = tmp_path / "p.npy"
    r = run("psf", "cooke-f50", "--method", method, "--size", 16, "--pupil-samples", 32, "--out", out)
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["method"] == method and np.load(out).shape == (16, 16)


def test_huygens_refuses_to_integrate_over_pixels(tmp_path):
    """Huygens samples pixel centres; asked to integrate it says so rather than returning
    point samples labelled as integrated."""
    r = run(
        "psf",
        "cooke-f50",
        "--method",
        "huygens",
        "--integrate",
        "--size",
        16,
        "--pupil-samples",
        32,
        "--out",
        tmp_path / "p.npy",
    )
    assert r.exit_code != 0 and "integrate: the Huygens PSF samples pixel centres" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "p.npy").exists()


def test_bad_lens_path_is_one_line_error(tmp_path):
    r = run("lens", "info", tmp_path / "missing.json")
    assert r.exit_code != 0
    assert "missing.json: no such lens file" in r.output and "Traceback" not in r.output


def test_bad_json_reports_line(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text('{\n "name": "x",\n "aperture": {"type": "epd" "value": 1}\n}\n')
    r = run("psf", p, "--out", tmp_path / "x.npy")
    assert r.exit_code != 0 and f"{p}:3:" in r.output


def test_unknown_glass_error(tmp_path):
    lens = json.loads((__import__("optix_e2e.lens").lens.BUNDLED_DIR / "cooke-f50.json").read_text())
    lens["surfaces"][2]["material"] = "F22"
    p = tmp_path / "l.json"
    p.write_text(json.dumps(lens))
    r = run("lens", "info", p, "--json")
    assert r.exit_code != 0 and "surface 3 (surfaces[2]) material: unknown glass 'F22'" in r.output


def test_engine_error_is_one_line(tmp_path):
    # at 35 deg every ray of the Cooke triplet fails (TIR / missed surface): no PSF
    r = run("psf", "cooke-f50", "--field-deg", 35, "--out", tmp_path / "x.npy")
    assert r.exit_code != 0 and r.output.startswith("Error: engine:") and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1


def test_subprocess_entry_point(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "optix_e2e", "lens", "info", str(tmp_path / "no.json")], capture_output=True, text=True
    )
    assert r.returncode != 0
    assert "Error:" in r.stderr and "no such lens file" in r.stderr and "Traceback" not in r.stderr


def test_demo_writes_grid_and_summary(tmp_path):
    r = run("demo", "--out", tmp_path, "--n-fields", 3, "--size", 32, "--pupil-samples", 32, "--rings", 16)
    assert r.exit_code == 0, r.output
    assert (tmp_path / "psf_grid.png").stat().st_size > 5000
    s = json.loads((tmp_path / "summary.json").read_text())
    assert [f["field_deg"] for f in s["fields"]] == [0.0, 10.0, 20.0]
    assert s["paraxial"]["efl_mm"] == pytest.approx(50.0, rel=1e-3)
    for f in s["fields"]:
        assert f["rms_spot_um"] > 0 and 0 < f["strehl_primary"] <= 1
        assert set(f["relative_illumination_per_channel"]) == {"R", "G", "B"}
    psfs = np.load(tmp_path / "psfs.npy")
    assert psfs.shape == (3, 3, 32, 32)
    assert np.allclose(psfs.sum(axis=(2, 3)), 1.0, atol=1e-6)
