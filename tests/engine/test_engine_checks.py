"""Physics and robustness checks of the engine through the bindings."""

import json

import numpy as np
import pytest

from optix_e2e import _engine
from optix_e2e.lens import Lens


def singlet(r1, r2, d, n, epd=2.0):
    return Lens(
        {
            "name": "singlet",
            "aperture": {"type": "epd", "value": epd},
            "fields_deg": [0.0],
            "wavelengths_nm": [550.0],
            "surfaces": [
                {"radius": r1, "thickness": d, "material": {"n": n}, "stop": True},
                {"radius": r2, "thickness": 100.0, "material": "air"},
            ],
        }
    )


@pytest.mark.parametrize("r1, r2, d, n", [(50.0, -50.0, 5.0, 1.5), (30.0, "inf", 3.0, 1.7), (40.0, 120.0, 8.0, 1.6)])
def test_thick_singlet_efl_matches_lensmaker(r1, r2, d, n):
    c1 = 1.0 / r1
    c2 = 0.0 if r2 == "inf" else 1.0 / r2
    power = (n - 1.0) * (c1 - c2 + (n - 1.0) * d * c1 * c2 / n)
    par = singlet(r1, r2, d, n).paraxial()
    assert par["efl_mm"] == pytest.approx(1.0 / power, rel=1e-12)
    # back focal length of a thick lens: f (1 - (n-1) d c1 / n)
    assert par["bfl_mm"] == pytest.approx((1.0 / power) * (1.0 - (n - 1.0) * d * c1 / n), rel=1e-12)


def test_fno_aperture_gives_epd():
    lens = singlet(50.0, -50.0, 5.0, 1.5)
    data = dict(lens.data, aperture={"type": "fno", "value": 8.0})
    par = Lens(data).paraxial()
    assert par["epd_mm"] == pytest.approx(par["efl_mm"] / 8.0, rel=1e-12)


def test_trace_field_beyond_the_lens_reports_failures_not_nan(cooke):
    px, py = np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21))
    keep = px**2 + py**2 <= 1
    r = cooke.trace_field(35.0, px[keep], py[keep], 550.0)
    status = np.asarray(r["status"])
    assert status.dtype == np.uint8 and np.all(status != 0)
    assert set(np.unique(status)) <= {1, 3}  # missed a surface or TIR
    for key in ("position", "direction", "opl"):
        assert np.all(np.isfinite(r[key])), key
    assert np.all(np.asarray(r["surface"])[status != 0] >= 0)


def test_trace_field_ok_rays(cooke):
    r = cooke.trace_field(20.0, np.array([0.0, 0.5, -0.5]), np.array([0.0, 0.3, -0.7]), 550.0)
    assert np.all(r["status"] == 0) and np.all(r["surface"] == -1)
    assert np.allclose(r["position"][:, 2], cooke.paraxial()["total_track_mm"])


def test_psf_without_transmitted_rays_raises(cooke):
    with pytest.raises(_engine.EngineError):
        cooke.psf(35.0, 550.0, "fft", size=16)


def test_engine_rejects_invalid_lens_naming_the_surface(cooke):
    data = json.loads(cooke.to_engine_json())
    data["surfaces"][2]["material"] = {"n": -1.0}
    with pytest.raises(_engine.LensError, match="surface 3"):
        _engine.validate_lens(json.dumps(data))


def test_psf_rgb_contract(cooke):
    psfs, ri, d = cooke.psf_rgb(14.0, size=32, pupil_samples=32)
    assert psfs.shape == (3, 32, 32) and ri.shape == (3,)
    assert np.allclose(psfs.sum(axis=(1, 2)), 1.0, atol=1e-9)
    assert np.all((ri > 0) & (ri <= 1.5))
    assert isinstance(d.get("warnings", []), list)


def test_psf_batch_contract(cooke):
    bad = json.loads(cooke.to_engine_json())
    bad["surfaces"][2]["material"] = {"n": -1.0}  # invalid design
    out = _engine.psf_batch(
        [cooke.to_engine_json(), json.dumps(bad)], [0.0, 20.0], cooke.rgb_channels("lens"), size=16, pupil_samples=32
    )
    assert out["psf"].shape == (2, 2, 3, 16, 16) and out["psf"].dtype == np.float32
    assert out["relative_illumination"].shape == (2, 2, 3)
    assert list(out["ok"]) == [True, False]
    assert out["errors"][0] is None and out["errors"][1]
    assert np.all(out["psf"][1] == 0)
    single, _, _ = cooke.psf_rgb(20.0, cooke.rgb_channels("lens"), size=16, pupil_samples=32)
    assert np.allclose(out["psf"][0, 1], single, atol=1e-6)


def test_psf_batch_into_a_callers_buffer():
    """psf_batch(out=...) overwrites every value of the caller's array (stale data, a
    design that does not parse -> zeros) with what it would have returned, and refuses
    an array of the wrong shape or dtype."""
    import numpy as np

    from optix_e2e import _engine
    from optix_e2e.lens import Lens

    js = Lens.load("paper-triplet").to_engine_json()
    ch = [[(650.0, 1.0)], [(550.0, 1.0)], [(470.0, 1.0)]]
    buf = np.full((3, 2, 3, 48, 48), 7.0, np.float32)
    r = _engine.psf_batch([js, "not json", js], [0.0, 14.9], ch, "fft", 1.0, 48, 48, out=buf)
    ref = _engine.psf_batch([js, "not json", js], [0.0, 14.9], ch, "fft", 1.0, 48, 48)
    assert r["psf"] is buf and np.array_equal(buf, ref["psf"])
    assert list(r["ok"]) == [True, False, True] and not buf[1].any()
    with pytest.raises(ValueError, match=r"out: need a C-contiguous float32 array of shape \[1, 1, 3, 48, 48\]"):
        _engine.psf_batch([js], [0.0], ch, "fft", 1.0, 48, 48, out=np.zeros((1, 1, 3, 32, 32), np.float32))
    with pytest.raises(TypeError):
        _engine.psf_batch([js], [0.0], ch, "fft", 1.0, 48, 48, out=np.zeros((1, 1, 3, 48, 48)))


def test_psf_batch_sensor_pixels():
    """psf_batch(sensor=(pitch_um, m)): each PSF also integrated over m x m sensor pixels
    (the dataset's psf_sensor), the same into a caller's buffer (stale values and a design
    that does not parse -> zeros); against the box-overlap weights built here in numpy."""
    import numpy as np

    from optix_e2e import _engine
    from optix_e2e.lens import Lens

    js = Lens.load("paper-triplet").to_engine_json()
    ch = [[(650.0, 1.0)], [(550.0, 1.0)], [(470.0, 1.0)]]
    r = _engine.psf_batch([js, "not json"], [0.0, 14.9], ch, "fft", 1.0, 48, 48, sensor=(5.86, 7))
    sens = r["psf_sensor"]
    assert sens.shape == (2, 2, 3, 7, 7) and sens.dtype == np.float32 and not sens[1].any()
    x, c = np.arange(48) - 24.0, (np.arange(7) - 3) * 5.86
    w = np.clip(np.minimum(x + 0.5, c[:, None] + 2.93) - np.maximum(x - 0.5, c[:, None] - 2.93), 0, None)
    np.testing.assert_allclose(
        sens[0], np.einsum("iy,kcyx,jx->kcij", w, r["psf"][0].astype(float), w), rtol=2e-6, atol=1e-9
    )
    # the 7 x 7 block (41 um) holds less than the 48 um window, most of an on-axis PSF
    assert np.all(sens[0].sum(axis=(-1, -2)) < r["psf"][0].sum(axis=(-1, -2)))
    assert np.all(sens[0, 0].sum(axis=(-1, -2)) > 0.9)
    buf = np.full((2, 2, 3, 7, 7), 7.0, np.float32)
    r2 = _engine.psf_batch([js, "not json"], [0.0, 14.9], ch, "fft", 1.0, 48, 48, sensor=(5.86, 7), sensor_out=buf)
    assert r2["psf_sensor"] is buf and np.array_equal(buf, sens)
    with pytest.raises(ValueError, match=r"sensor_out: need a C-contiguous float32 array of shape \[2, 2, 3, 7, 7\]"):
        _engine.psf_batch(
            [js, "not json"], [0.0, 14.9], ch, "fft", 1.0, 48, 48, sensor=(5.86, 7), sensor_out=buf[:, :, :, :5]
        )
    with pytest.raises(ValueError, match="sensor_out without sensor"):
        _engine.psf_batch([js], [0.0], ch, "fft", 1.0, 48, 48, sensor_out=buf[:1, :1])
    with pytest.raises(ValueError, match="positive pitches"):
        _engine.psf_batch([js], [0.0], ch, "fft", 1.0, 48, 48, sensor=(0.0, 7))
