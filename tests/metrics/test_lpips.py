"""Offline LPIPS (optix_e2e.metrics.lpips) against the original's distances on its example images
(../shared/lpips-reference: AlexNet v0.1, ex_ref-ex_p0 = 0.722, ex_ref-ex_p1 = 0.138)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import WHERE_SHARED, shared_dir
from PIL import Image

import optix_e2e
from optix_e2e.metrics import lpips as lpips_module
from optix_e2e.metrics.lpips import LPIPS, WEIGHTS_SHA256, LPIPSWeightsError, lpips, weights_digest, weights_path

LPIPS_REF = shared_dir("lpips-reference")


def _image(name: str) -> torch.Tensor:
    path = LPIPS_REF / name
    if not path.is_file():
        pytest.fail(f"{path}: the LPIPS reference images are missing ({WHERE_SHARED})", pytrace=False)
    a = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
    return torch.from_numpy(a).permute(2, 0, 1)


def test_reproduces_the_original_distances():
    ref, p0, p1 = _image("ex_ref.png"), _image("ex_p0.png"), _image("ex_p1.png")
    d = lpips(torch.stack([ref, ref]), torch.stack([p0, p1]))
    assert d.shape == (2,)
    assert round(float(d[0]), 3) == 0.722 and round(float(d[1]), 3) == 0.138, d
    assert float(lpips(ref, ref)) == pytest.approx(0.0, abs=1e-6)
    # symmetric, and the unbatched call gives the batched value
    assert float(lpips(p0, ref)) == pytest.approx(float(d[0]), rel=1e-5)


def test_is_differentiable_and_frozen():
    m = LPIPS()
    assert not any(p.requires_grad for p in m.parameters())
    x = _image("ex_p1.png")[None].requires_grad_(True)
    m(x, _image("ex_ref.png")[None]).sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="one shape"):
        m(torch.zeros(1, 3, 64, 64), torch.zeros(1, 3, 32, 32))


def test_shipped_weights_match_their_checksum_and_load_no_code():
    """The package carries the weights (no side install): float32 arrays in an .npz read with
    allow_pickle=False, checked against the recorded digest on every load."""
    path = weights_path()
    assert path.is_relative_to(Path(optix_e2e.__file__).parent), path
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    assert weights_digest(arrays) == WEIGHTS_SHA256
    assert {a.dtype for a in arrays.values()} == {np.dtype(np.float32)}
    assert sum(a.size for a in arrays.values()) == 2_470_848
    assert issubclass(LPIPSWeightsError, RuntimeError)


def test_damaged_weights_are_refused(tmp_path, monkeypatch):
    good = weights_path()
    with np.load(good, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["lin.0"] = arrays["lin.0"] * np.float32(2)  # valid file, wrong numbers
    bad = tmp_path / "w.npz"
    np.savez(bad, **arrays)
    monkeypatch.setattr(lpips_module, "WEIGHTS", bad)
    lpips_module._state.cache_clear()
    try:
        with pytest.raises(LPIPSWeightsError, match="checksum"):
            LPIPS()
        bad.write_bytes(b"not a zip")
        lpips_module._state.cache_clear()
        with pytest.raises(LPIPSWeightsError, match="not the LPIPS AlexNet weights"):
            LPIPS()
        monkeypatch.setattr(lpips_module, "WEIGHTS", tmp_path / "absent.npz")
        lpips_module._state.cache_clear()
        with pytest.raises(LPIPSWeightsError, match="missing from the package"):
            LPIPS()
    finally:
        lpips_module._state.cache_clear()


def test_cli_metrics_json(tmp_path):
    import json

    from click.testing import CliRunner

    from optix_e2e.cli import main

    ref, p0 = str(LPIPS_REF / "ex_ref.png"), str(LPIPS_REF / "ex_p0.png")
    r = CliRunner().invoke(main, ["metrics", p0, ref, "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert set(out) >= {"psnr_db", "ssim", "lpips", "haarpsi"}
    assert round(out["lpips"], 3) == 0.722 and 0 < out["ssim"] < 1 and 0 < out["haarpsi"] < 1
    r = CliRunner().invoke(main, ["metrics", ref, ref, "--json"])
    assert r.exit_code == 0 and json.loads(r.stdout)["lpips"] == pytest.approx(0.0, abs=1e-6)
    small = tmp_path / "small.png"
    Image.new("RGB", (32, 32)).save(small)
    r = CliRunner().invoke(main, ["metrics", str(small), ref])
    assert r.exit_code == 1 and "one size" in r.output
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    r = CliRunner().invoke(main, ["metrics", str(bad), ref])
    assert r.exit_code == 1 and "cannot read as an image" in r.output
