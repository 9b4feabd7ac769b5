"""lens.surface.sag at one height (the design checks' scalar path) gives the bits of the array
path at that height, inside and beyond a conic's reach, with and without ``clip``."""

from __future__ import annotations

import numpy as np

from optix_e2e.lens.surface import sag


def test_the_scalar_sag_has_the_array_sags_bits():
    rng = np.random.default_rng(0)
    n_nan = 0
    for _ in range(3000):
        s = {"radius": float(rng.choice([-1, 1]) * rng.uniform(3, 200)), "conic": float(rng.uniform(-3, 2))}
        if rng.random() < 0.5:
            s["aspheric"] = {"a2": float(rng.normal() * 1e-3), "a4": float(rng.normal() * 1e-4), "a6": 1e-7}
        elif rng.random() < 0.2:
            s["aspheric"] = {"a1": 1e-3, "a3": -1e-5, "a4": 1e-6}  # an odd asphere
        r = float(rng.uniform(0, 12)) * (1 if rng.random() < 0.9 else -1)
        for clip in (False, True):
            for one in (r, np.float64(r), np.float32(r)):
                a, b = sag(s, one, clip=clip), sag(s, np.array([float(one)]), clip=clip)[0]
                assert (np.isnan(a) and np.isnan(b)) or a == b, (s, one, clip, a, b)
                n_nan += bool(np.isnan(a))
    assert n_nan > 0  # heights beyond some conic's reach were among them
    assert sag({"radius": "inf"}, 3) == 0.0 and np.isnan(sag({"radius": 2.0}, 2.5))
