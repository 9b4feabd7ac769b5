"""Make the bundled `apo-gauss-8e-mv`: the eight-element `apo-gauss-8e` (JP 2025-108279 A,
Example 1) scaled so that its full field, 23.94 deg, lands on the corner of the IMX249-class
sensor the camera pipeline models (half-diagonal 0.5 * hypot(1920, 1200) * 5.86 um = 6.634
mm), with the camera's channel wavelengths.  A 1/1.2" machine-vision lens of about 15 mm.

    python scripts/make_apo_gauss_8e_mv.py python/optix_e2e/bundled/apo-gauss-8e-mv.json \
        --given-space runs/agm/given.toml

``--given-space`` also writes apo-gauss-8e's provisional space (radii +-5 %, air gaps +-20 %)
at the new scale, with the manufacturability limits scaled: the given space of the tolerance
analysis that sets the bundled space's ranges (docs/designs.md).

The scale factor is the half-diagonal over the real chief ray's image height at 23.94 deg
(550 nm, paraxial aiming), so that distortion cannot leave the sensor's corner unimaged.
"""

import argparse
import dataclasses
import json
import math

import numpy as np

from optix_e2e import _engine
from optix_e2e.lens import Lens
from optix_e2e.lens.scale import scale_lens
from optix_e2e.lens_design.space import ParameterSpace, load_space

HALF_DIAGONAL_MM = 0.5 * math.hypot(1920, 1200) * 5.86e-3
WAVELENGTHS_NM = [470.0, 550.0, 650.0]  # the camera's B, G, R channel centres (as paper-triplet)


LENGTH_KINDS = ("radius", "thickness", "air_gap")


def write_given_space(path: str, factor: float) -> None:
    """apo-gauss-8e's space with its ranges and its manufacturability limits (rounded down to
    0.01 mm) times ``factor``."""
    space, _ = load_space("apo-gauss-8e")
    other = [p.name for p in space.params if p.kind not in LENGTH_KINDS]
    if other:
        raise SystemExit(
            f"apo-gauss-8e's space has parameters that are not lengths ({', '.join(other)}): scale them by hand"
        )
    params = [dataclasses.replace(p, min=p.min * factor, max=p.max * factor) for p in space.params]
    limits = {k: math.floor(v * factor * 100) / 100 for k, v in space.constraints.items()}
    ParameterSpace(params, constraints=limits).save_toml(
        path,
        lens_ref="apo-gauss-8e-mv",
        description=f"apo-gauss-8e's provisional space (radii +-5 %, air gaps +-20 %) scaled by {factor}: the "
        f"given space of the tolerance analysis (scripts/make_apo_gauss_8e_mv.py)",
    )


def main(out: str, given_space: str | None) -> None:
    from optix_e2e.lens.model import BUNDLED_DIR

    # the file as written (glasses by name), not the resolved prescription
    src = json.loads((BUNDLED_DIR / "apo-gauss-8e.json").read_text(encoding="utf-8"))
    d = dict(src, wavelengths_nm=WAVELENGTHS_NM, primary_wavelength_nm=550.0)
    d.pop("wavelength_weights", None)
    field = max(d["fields_deg"])
    tr = _engine.trace_field(json.dumps(Lens(d).data), field, np.zeros(1), np.zeros(1), 550.0, "paraxial")
    assert tr["status"][0] == 0, "chief ray failed"
    h = abs(float(tr["position"][0, 1]))
    factor = round(HALF_DIAGONAL_MM / h, 6)
    out_d = scale_lens(d, factor)
    out_d["name"] = "apo-gauss-8e-mv"
    out_d["source"] = f"apo-gauss-8e (JP 2025-108279 A, Example 1) scaled by {factor} (scripts/make_apo_gauss_8e_mv.py)"
    out_d["description"] = (
        f"The eight-element apo-gauss-8e (JP 2025-108279 A, Example 1, Cosina; 8 elements in 6 groups, all "
        f"spherical) scaled by {factor} so that the real chief ray of its full field, {field} deg, lands on the "
        f"IMX249 sensor's corner ({HALF_DIAGONAL_MM:.4f} mm), and with the camera's channel wavelengths 470 / 550 "
        f"/ 650 nm (the patent: F, d, C): a 1/1.2-inch machine-vision lens for the paper's Sec. 6.2 experiment. "
        f"Radii, thicknesses, clear semi-diameters (Beam42's estimates, scaled) and the back focus are the "
        f"patent's times the factor; glasses, f-number and field angles unchanged; not re-optimized."
    )
    for s in out_d["surfaces"]:  # 9 significant digits: the .zmx round trip stays exact
        for k in ("radius", "thickness", "semi_diameter"):
            if isinstance(s.get(k), float):
                s[k] = float(f"{s[k]:.9g}")
    Lens(dict(out_d))  # validates
    with open(out, "w", encoding="utf-8") as f:
        json.dump(out_d, f, indent=1)
        f.write("\n")
    if given_space:
        write_given_space(given_space, factor)
    print(json.dumps({"factor": factor, "chief_height_patent_mm": h, "out": out, "given_space": given_space}))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="the lens JSON to write")
    ap.add_argument("--given-space", default=None, help="also write the scaled provisional space (TOML)")
    a = ap.parse_args()
    main(a.out, a.given_space)
