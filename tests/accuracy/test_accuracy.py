"""``optix bench accuracy`` (optix_e2e.accuracy): metrics against closed forms, the Pareto
front, the converged reference, and a quick run of the whole bench."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from optix_e2e.accuracy import converged_reference, ee_radius, rel_l1, rel_l2, render_error, scene_chart
from optix_e2e.accuracy.chart import mark_pareto
from optix_e2e.accuracy.sweep import channel_wavelengths, method_settings
from optix_e2e.cli import main
from optix_e2e.lens import Lens


def _gaussian(size: int, sigma: float) -> np.ndarray:
    y, x = np.indices((size, size)) - size // 2
    g = np.exp(-(x * x + y * y) / (2 * sigma * sigma))
    return g / g.sum()


def test_metrics_against_closed_forms():
    g = _gaussian(129, 6.0)
    # 2-D Gaussian: encircled energy 1 - exp(-r^2 / 2 sigma^2) -> r80 = sigma sqrt(2 ln 5)
    assert ee_radius(g, 0.5, 0.8) == pytest.approx(0.5 * 6.0 * math.sqrt(2 * math.log(5)), rel=0.02)
    assert rel_l1(g, g) == 0 and rel_l2(g, g) == 0
    assert rel_l1(1.1 * g, g) == pytest.approx(0.1) and rel_l2(0.9 * g, g) == pytest.approx(0.1)
    img = scene_chart(96)
    assert img.shape == (96, 96) and 0 <= img.min() and img.max() <= 1 and img.std() > 0.15
    assert render_error(g, g, img) == 0
    # a wider blur changes the rendered image, more for more blur
    e1, e2 = render_error(_gaussian(129, 7.0), g, img), render_error(_gaussian(129, 9.0), g, img)
    assert 0 < e1 < e2


def test_pareto_front():
    pts = [{"time_s": t, "rel_l1": e} for t, e in [(1, 0.5), (2, 0.6), (3, 0.1), (4, 0.1), (5, 0.01), (0.5, 0.9)]]
    mark_pareto(pts)
    assert [p["pareto"] for p in pts] == [True, False, True, False, True, True]


def test_channel_wavelengths_are_a_quadrature_of_the_response():
    for k in (1, 3, 5, 9):
        ch = channel_wavelengths("G", k)
        assert len(ch) == k and sum(w for _, w in ch) == pytest.approx(1.0)
        assert sum(wl * w for wl, w in ch) == pytest.approx(540.0, abs=1e-9)  # symmetric band
    assert channel_wavelengths("G", 1) == [(540.0, 1.0)]


def test_reference_converges_by_doubling():
    """Doubling the pupil sampling until two Huygens PSFs agree: the result is within the
    tolerance of the previous one, keeps the energy the engine reports in the window, and
    an unreachable tolerance is an error, not a silently unconverged reference."""
    lens = Lens.load("paper-triplet")
    ref = converged_reference(lens.to_engine_json(), 0.0, 550.0, size=64, pixel_um=1.0, start=64, tol=2e-2)
    assert ref.convergence <= 2e-2 and ref.pupil_samples >= 128
    assert 0.99 < ref.psf.sum() / ref.diagnostics["energy_in_window"] < 1.01
    with pytest.raises(RuntimeError, match="did not converge"):
        converged_reference(
            lens.to_engine_json(), 0.0, 550.0, size=64, pixel_um=1.0, start=16, tol=1e-6, max_samples=32
        )


@pytest.mark.slow
def test_bench_accuracy_quick_run(tmp_path):
    r = CliRunner().invoke(main, ["bench", "accuracy", "--quick", "--lens", "paper-triplet", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    rep = json.loads((tmp_path / "accuracy.json").read_text())
    for f in rep["files"]:
        assert (tmp_path / f).stat().st_size > 0
    rows = list(csv.DictReader(open(tmp_path / "rows.csv")))
    assert len(rows) == 2 * len(method_settings(quick=True)) == 42  # 2 cases (axis, edge)
    # a setting the engine refuses (its window holding more than the transmitted energy) is
    # a row with the error; every other row has its time and error
    refused = [r for r in rows if r.get("error")]
    assert all("PsfError" in r["error"] for r in refused) and len(refused) < len(rows) // 2
    assert all(float(r["time_s"]) > 0 and float(r["rel_l1"]) >= 0 for r in rows if not r.get("error"))
    summary = list(csv.DictReader(open(tmp_path / "summary.csv")))
    front = [s for s in summary if s["pareto"] == "True"]
    assert front and len(front) < len(summary)
    # on the front, more time buys less error
    front.sort(key=lambda s: float(s["time_s"]))
    assert all(float(a["rel_l1"]) > float(b["rel_l1"]) for a, b in zip(front, front[1:]))
    # converged FFT settings beat the coarsest Huygens and geometric ones by far
    by = {s["setting"]: float(s["rel_l1"]) for s in summary}
    assert by["fft N=64"] < 0.1 and by["fft N=64"] < by["geometric N=16"]
    # the coarsest Huygens sum aliases: refused by its energy check, or far off where it passes
    assert by.get("huygens N=16", 1.0) > 0.1
    sampling = list(csv.DictReader(open(tmp_path / "sampling.csv")))
    spec = {
        (s["channel"], int(s["n_wavelengths"])): float(s["rel_l1"]) for s in sampling if s["experiment"] == "spectral"
    }
    assert all(spec[(c, 9)] < spec[(c, 1)] for c in "RGB")
    fields = {int(s["k_fields"]): float(s["rel_l1"]) for s in sampling if s["experiment"] == "fields"}
    assert fields[13] < fields[2]
