"""Lens mass (lens/mass.py): element volumes against closed forms, the flange rule, and the
bundled lenses' figures (issue 57's form-factor comparison)."""

from __future__ import annotations

import math

import pytest

from optix_e2e.errors import InputError
from optix_e2e.lens import Lens
from optix_e2e.lens.mass import element_volume_mm3, lens_mass


def test_a_plano_convex_element_has_the_spherical_caps_volume():
    """Sphere of radius R over a clear radius a, plane back, centre thickness t: the cylinder
    of height t - h plus the cap of height h = R - sqrt(R^2 - a^2), pi h^2 (3R - h) / 3
    (relative 1e-10: the quadrature of the square root)."""
    R, a, t = 12.0, 5.0, 4.0
    h = R - math.sqrt(R * R - a * a)
    exact = math.pi * a * a * (t - h) + math.pi * h * h * (3 * R - h) / 3
    vol, outer = element_volume_mm3({"radius": R, "semi_diameter": a}, {"radius": "inf", "semi_diameter": a}, t)
    assert outer == a and vol == pytest.approx(exact, rel=1e-10)


def test_a_surface_smaller_than_the_element_continues_flat():
    """A plate whose back clear aperture is smaller than its front's: the element's outer
    radius is the larger, the back flat out to it (a cylinder, pi a^2 t); a sphere on the
    small side adds its cap's volume over the plane at its rim's sag."""
    vol, outer = element_volume_mm3(
        {"radius": "inf", "semi_diameter": 5.0}, {"radius": "inf", "semi_diameter": 3.0}, 2.0
    )
    assert outer == 5.0 and vol == pytest.approx(math.pi * 25.0 * 2.0, rel=1e-12)
    R, b, t = -10.0, 3.0, 2.0  # the back convex towards the image (thinner off axis), clear radius 3 of 5
    h = abs(R) - math.sqrt(R * R - b * b)
    cap = math.pi * h * h * (3 * abs(R) - h) / 3
    vol, _ = element_volume_mm3({"radius": "inf", "semi_diameter": 5.0}, {"radius": R, "semi_diameter": b}, t)
    # flat at the rim's sag (-h) beyond 3 mm: a plate t - h thick over the whole 5 mm, plus the
    # cap of height h over the inner 3 mm
    expect = math.pi * 25.0 * (t - h) + cap
    assert vol == pytest.approx(expect, rel=1e-10)


def test_the_bundled_lenses_count_their_elements_and_name_an_unknown_glass():
    tri = lens_mass(Lens.load("paper-triplet").raw)
    assert tri["n_elements"] == 3 and [e["material"] for e in tri["elements"]] == ["PMMA", "N-SF11", "PMMA"]
    assert tri["mass_g"] == pytest.approx(sum(e["volume_mm3"] * 1e-3 * e["density_g_cm3"] for e in tri["elements"]))
    assert 0.5 < tri["mass_g"] < 2.0  # 1.03 g: the triplet's three small elements
    dbl = lens_mass(Lens.load("paper-doublet").raw)
    assert dbl["n_elements"] == 2
    raw = Lens.load("paper-triplet").raw
    raw["surfaces"][0]["material"] = "UNOBTAINIUM"
    with pytest.raises(InputError, match="surface 1: no density known for 'UNOBTAINIUM'"):
        lens_mass(raw)
