"""benches/gpu.py, the GPU check of issue 36: it runs in its smallest form on the CPU and writes
the JSON its reader expects. Only the structure is checked, never a time (a benchmark measures;
the machine is shared)."""

from __future__ import annotations

import json

import pytest


@pytest.mark.slow
def test_the_smallest_run_writes_every_figure(tmp_path, capsys, load_bench):
    bench = load_bench("gpu")
    bench.main(["--out", str(tmp_path), "--smoke", "--devices", "cpu", "--precision", "fp32,bf16"])
    res = json.loads((tmp_path / "gpu.json").read_text())
    assert res["format"] == "optix-gpu-bench/1"
    for k in ("torch", "cuda", "gpu", "cpu_count", "torch_threads"):
        assert k in res["machine"]
    parts = res["devices"]["cpu"]["fp32"]
    assert set(parts) == set(bench.PARTS)
    for name in ("design", "design_exact"):
        assert set(parts[name]["median_ms"]) == {*bench.DESIGN_STAGES, "step"}, name
        assert 0.0 < parts[name]["host_fraction"] < 1.0, name  # the scenes at least; never the whole step
    ms = parts["design_exact"]["median_ms"]  # its optics stage is the engine's, on the CPU: counted
    assert parts["design_exact"]["host_fraction"] >= (ms["batch"] + ms["optics"]) / ms["step"] - 1e-3
    for name, r in parts.items():
        assert "error" not in r, (name, r.get("error"))
        assert r["steps"] == 1 and r["steps_per_s"] > 0 and r["peak_mib"] is None  # no GPU memory on the CPU
        assert all(v >= 0 for v in r["median_ms"].values())
    low = res["devices"]["cpu"]["bf16"]  # the CPU alone: timed at every precision asked for
    assert set(low) == set(bench.NETWORK_PARTS) and not any("error" in r for r in low.values()), low
    assert res["ratios"] == {}  # no GPU here: nothing to compare
    printed = capsys.readouterr().out.splitlines()
    assert "cpu fp32 surrogate step" in "\n".join(printed) and printed[-1].startswith("wall ")


def test_ratios_are_cpu_time_over_gpu_time_per_stage(load_bench):
    bench = load_bench("gpu")
    devices = {
        "cpu": {"fp32": {"design": {"median_ms": {"step": 100.0, "isp": 30.0}}, "detector": {"error": "x"}}},
        "cuda": {
            "fp32": {"design": {"median_ms": {"step": 4.0, "isp": 3.0}}, "detector": {"median_ms": {"step": 1.0}}},
            "bf16": {"design": {"median_ms": {"step": 2.0}}},
        },
    }
    assert bench.ratios(devices) == {
        "design step cpu/cuda-fp32": 25.0,
        "design isp cpu/cuda-fp32": 10.0,
        "design step cpu/cuda-bf16": 50.0,
    }
