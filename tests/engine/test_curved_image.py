"""A curved image surface (a curved sensor, as in vendor files with CURV on the image
surface): rays end on the sphere, the sagittal image of a thin lens lies on its Seidel
sagittal surface, and the wave-optics analyses of a field use the plane through the
chief ray's point on the sphere (crates/psf-engine/src/image.rs)."""

import copy

import numpy as np
import pytest

from optix_e2e._engine import LensError
from optix_e2e.lens import Lens
from optix_e2e.lens.prescription import PrescriptionError

N_GLASS, R_LENS, EPD = 1.5, 100.0, 10.0


def thin_lens(image_radius=None, stop_to_image=None) -> Lens:
    """An equiconvex singlet (n 1.5, f ~ 100 mm, f/10) with its stop on the lens, the image
    at the paraxial focus, optionally curved."""
    data = {
        "name": "singlet",
        "aperture": {"type": "epd", "value": EPD},
        "fields_deg": [0.0, 10.0],
        "wavelengths_nm": [587.6],
        "surfaces": [
            {"radius": R_LENS, "thickness": 1.0, "material": {"n": N_GLASS}, "stop": True},
            {"radius": -R_LENS, "thickness": 100.0, "material": "air"},
        ],
    }
    lens = Lens(data)
    data["surfaces"][-1]["thickness"] = float(lens.paraxial()["bfl_mm"])
    if image_radius is not None:
        data["image"] = {"radius": image_radius}
    return Lens(data)


def test_rays_end_on_the_sphere_where_their_straight_line_meets_it():
    """The engine's intersection against numpy's: each ray traced to the flat image plane,
    continued as a line to the sphere of radius R through the image vertex."""
    radius = -60.0
    flat, curved = thin_lens(), thin_lens(radius)
    rng = np.random.default_rng(0)
    px, py = rng.uniform(-0.7, 0.7, 40), rng.uniform(-0.7, 0.7, 40)
    for field in (0.0, 6.0, 10.0):
        a, b = flat.trace_field(field, px, py), curved.trace_field(field, px, py)
        assert np.all(a["status"] == 0) and np.all(b["status"] == 0)
        z0 = float(flat.paraxial()["image_z_mm"])
        centre = np.array([0.0, 0.0, z0 + radius])
        p, d = a["position"], a["direction"]
        # |p + t d - centre|^2 = R^2, the root nearest the plane (the vertex sheet)
        q = p - centre
        bq, cq = np.sum(q * d, axis=1), np.sum(q * q, axis=1) - radius**2
        t = -bq - np.sign(radius) * np.sqrt(bq**2 - cq)
        want = p + t[:, None] * d
        np.testing.assert_allclose(b["position"], want, atol=1e-9)
        np.testing.assert_allclose(b["direction"], d, atol=1e-12)
        # optical path grows by the extra (signed) distance in air
        np.testing.assert_allclose(b["opl"] - a["opl"], t, atol=1e-9)


def test_sagittal_image_of_a_thin_lens_with_its_stop_on_it_lies_on_the_seidel_surface():
    """Seidel: a thin lens with the stop at the lens images a sagittal fan onto a sphere of
    radius -n f / (n + 1) (Petzval -n f plus the astigmatism of a stop at the lens). On that
    sensor the sagittal rays of a 6 degree field meet the chief ray in x to within a small
    fraction of their spread on the flat sensor; on the Petzval sphere they do not."""
    f = float(thin_lens().paraxial()["efl_mm"])
    r_sag, r_petzval = -N_GLASS * f / (N_GLASS + 1), -N_GLASS * f
    px, py = np.array([-0.3, 0.3]), np.zeros(2)

    def spread(lens):
        x = lens.trace_field(6.0, px, py)["position"][:, 0]
        return abs(x[1] - x[0])

    flat = spread(thin_lens())
    assert flat > 0.02  # mm: the flat sensor sees the sagittal defocus
    assert spread(thin_lens(r_sag)) < 0.03 * flat
    assert spread(thin_lens(r_petzval)) > 0.3 * flat


def test_psf_and_wavefront_of_a_field_use_the_plane_through_the_chief_rays_point():
    """The PSF and the wavefront at a field on the curved sensor are those of a flat sensor
    moved to where the chief ray meets the sphere: the same numbers (to the rounding of the
    image position, summed in another order)."""
    curved = thin_lens(-70.0)
    chief = curved.trace_field(8.0, np.zeros(1), np.zeros(1))["position"][0]
    moved = copy.deepcopy(thin_lens().data)
    moved["surfaces"][-1]["thickness"] += chief[2] - float(curved.paraxial()["image_z_mm"])
    moved = Lens(moved)
    a, _ = curved.psf(8.0, size=64)
    b, _ = moved.psf(8.0, size=64)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6 * a.max())
    np.testing.assert_allclose(curved.wavefront(8.0)["rms_waves"], moved.wavefront(8.0)["rms_waves"], rtol=1e-8)
    # ... and they differ from the flat sensor's
    flat, _ = thin_lens().psf(8.0, size=64)
    assert np.abs(a - flat).sum() > 0.1


@pytest.mark.parametrize(
    "image, msg",
    [
        ({"radius": 0}, r"image\.radius: must not be 0"),
        ({"radius": "flat"}, r"image\.radius: must be a number"),
        ({"radius": 5.0, "semi_diameter": 6.0}, r"semi_diameter.* exceeds the curved image surface"),
    ],
)
def test_bad_image_radius_is_one_clear_error(image, msg):
    data = copy.deepcopy(thin_lens().data)
    data["image"] = image
    with pytest.raises((PrescriptionError, LensError), match=msg):
        Lens(data).paraxial()
