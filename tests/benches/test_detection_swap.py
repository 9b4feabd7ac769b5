"""benches/detection_swap.py: lens x processing on a detection run's held-out scenes. Its
diagonal must be the run's own cameras (evaluated again from the saved ISP and detector, the
same detections as the run saved), and each effect the difference of its two cells."""

import json

import pytest


@pytest.mark.slow
def test_the_swap_bench_rebuilds_the_runs_cameras(tmp_path, optix, smoke_design, load_bench):
    run = tmp_path / "det"
    r = optix(*smoke_design("detection", run))
    assert r.returncode == 0, r.stdout + r.stderr
    bench = load_bench("detection_swap")
    # the run's own cameras come from its saved detections (the same cache key: code, sensor,
    # lens, processing, scenes); only the crossed cells are evaluated and kept in cells/
    bench.main([str(run), "--out", str(tmp_path / "first"), "--threads", "1"])
    kept = {f.name for f in (tmp_path / "first" / "cells").iterdir()}
    assert kept == {"e2e_A__nominal.json", "nominal__e2e_A.json"}
    out = bench.main([str(run), "--out", str(tmp_path / "swap"), "--recheck", "--threads", "1"])
    res = json.loads((run / "results.json").read_text())

    # the saved detections of both cameras, and the same cameras rebuilt from their checkpoints
    for lens, who in (("nominal", "nominal"), ("e2e A", "end_to_end")):
        for k in ("map_50", "map"):
            again = out["recheck"][lens][k]
            assert again["again"] == pytest.approx(again["saved"], abs=1e-9)
            assert again["saved"] == pytest.approx(res[who][k], abs=1e-9)
    cells = {(c["lens"], c["processing"]): c for c in out["cells"]}
    assert set(cells) == {(ln, pn) for ln in ("nominal", "e2e A") for pn in ("nominal", "e2e A")}
    assert out["f_numbers"]["e2e A"] == pytest.approx(res["end_to_end"]["f_number"], abs=1e-5)

    effects = {e["name"]: e for e in out["effects"]}
    lens = effects["lens e2e A - nominal, processing nominal"]
    diff = cells[("e2e A", "nominal")]["map_50"] - cells[("nominal", "nominal")]["map_50"]
    # mAP is torchmetrics' float32: a difference of two cells agrees to float32's rounding near 1
    assert lens["map_50"]["mean"] == pytest.approx(diff, abs=1e-6)
    whole = effects["camera e2e A - nominal"]  # the run's own paired figure
    assert whole["map_50"]["mean"] == pytest.approx(res["paired"]["map_50"]["mean"], abs=1e-9)
    assert whole["map_50"]["ci95"] == pytest.approx(res["paired"]["map_50"]["ci95"], abs=1e-9)
    proc = effects["processing e2e A - nominal, lens e2e A"]
    diff = cells[("e2e A", "e2e A")]["map"] - cells[("e2e A", "nominal")]["map"]
    assert proc["map"]["mean"] == pytest.approx(diff, abs=1e-6)
    assert (tmp_path / "swap" / "detection_swap.md").read_text().count("\n| lens e2e A - nominal") == 2

    # a blurred nominal lens as a control: the cells already evaluated come from the bench's cache
    again = bench.main([str(run), "--out", str(tmp_path / "swap"), "--blur-um", "6", "--threads", "1"])
    blur = {(c["lens"], c["processing"]): c for c in again["cells"]}
    assert ("nominal blur 6 um", "nominal") in blur
    for k, c in cells.items():
        assert blur[k] == c

    # the table over seeds: one swap twice gives its own effects, an interval of zero width
    tab = bench.main(["--seeds", str(tmp_path / "swap"), str(tmp_path / "swap"), "--out", str(tmp_path / "t")])
    row = next(r for r in tab["effects"] if r["name"] == lens["name"])
    assert row["map_50"]["mean"] == pytest.approx(lens["map_50"]["mean"], abs=1e-12)
    assert row["map_50"]["seeds_ci95"] == pytest.approx([lens["map_50"]["mean"]] * 2, abs=1e-12)
    assert (tmp_path / "t" / "swap_seeds.md").is_file()


def test_the_swap_bench_refuses_a_folder_that_is_not_a_finished_run(tmp_path, load_bench):
    bench = load_bench("detection_swap")
    with pytest.raises(SystemExit, match="not a finished design run"):
        bench.main([str(tmp_path), "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit, match="no detection_swap.json"):
        bench.main(["--seeds", str(tmp_path), "--out", str(tmp_path / "o")])
    (tmp_path / "detection_swap.json").write_text("{not json")
    with pytest.raises(SystemExit, match="not a readable swap"):
        bench.main(["--seeds", str(tmp_path), "--out", str(tmp_path / "o")])
    for f in ("config.json", "results.json", "nominal_state.pt", "end_to_end_state.pt"):
        (tmp_path / f).write_text("{}")
    (tmp_path / "config.json").write_text('{"no_such_setting": 1}')
    with pytest.raises(SystemExit, match="not a readable design run"):
        bench.main([str(tmp_path), "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit):  # argparse: one line on stderr
        bench.main([str(tmp_path), "--out", str(tmp_path / "o"), "--blur-um", "0"])


def test_the_control_blur_is_a_gaussian_of_the_asked_width_and_keeps_the_light(load_bench):
    import torch

    bench = load_bench("detection_swap")
    psf = torch.zeros(2, 3, 41, 41)
    psf[..., 20, 20] = torch.tensor([1.0, 0.5, 0.25])  # a point on the pixel grid, three channels
    out = bench.gaussian_blur(psf, 2.0)
    assert torch.allclose(out.sum((-2, -1)), psf.sum((-2, -1)), rtol=1e-6)
    x = torch.arange(41.0) - 20
    w = out[0, 0] / out[0, 0].sum()
    var_x = float((w.sum(0) * x**2).sum())
    assert var_x == pytest.approx(4.0, rel=1e-3)  # sigma^2, the sampled Gaussian's variance
    assert bench.gaussian_blur(psf, 2.0)[1, 2].sum() == pytest.approx(0.25, rel=1e-6)
