//! Shared helpers: the classic Cooke triplet of ../shared/reference (computed with another
//! tool), converted to our prescription format, and small synthetic lenses.
#![allow(dead_code)]

use psf_engine::Lens;
use serde_json::{json, Value};
use std::path::PathBuf;

/// As tests/conftest.py finds it: `OPTIX_REFERENCE_DIR` where set, else
/// `$OPTIX_SHARED_DIR/reference`, else `shared/reference` beside the repository.
pub fn reference_dir() -> PathBuf {
    let p = std::env::var_os("OPTIX_REFERENCE_DIR")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("OPTIX_SHARED_DIR").map(|d| PathBuf::from(d).join("reference")))
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/reference"));
    assert!(
        p.join("cooke_triplet.json").exists(),
        "reference data missing: expected {} (shared/ beside the repo, or set OPTIX_SHARED_DIR \
         or OPTIX_REFERENCE_DIR)",
        p.display()
    );
    p
}

pub fn read_json(name: &str) -> Value {
    let path = reference_dir().join(name);
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

/// The reference Cooke triplet in our JSON schema, glasses by their database formulas.
pub fn cooke_json() -> Value {
    let r = read_json("cooke_triplet.json");
    let mut surfaces = vec![];
    for s in r["surfaces"].as_array().unwrap() {
        let role = s["role"].as_str().unwrap();
        if role != "refracting" {
            continue;
        }
        let m = &s["material_after"];
        let material = if m["name"] == "air" {
            json!("air")
        } else {
            let kind: u64 = m["formula"]
                .as_str()
                .unwrap()
                .trim_start_matches("formula ")
                .parse()
                .unwrap();
            json!({"formula": kind, "coefficients": m["coefficients"], "range_um": m["valid_range_um"], "name": m["name"]})
        };
        surfaces.push(json!({
            "radius": s["radius_mm"], "conic": s["conic"], "thickness": s["thickness_after_mm"],
            "material": material, "stop": s["is_stop"],
        }));
    }
    json!({
        "name": "cooke-f50", "aperture": {"type": "epd", "value": r["aperture"]["value"]},
        "fields_deg": r["fields"]["values_deg"], "wavelengths_nm": [480.0, 550.0, 650.0],
        "primary_wavelength_nm": 550.0, "surfaces": surfaces,
    })
}

pub fn cooke() -> Lens {
    Lens::from_json(&cooke_json().to_string()).unwrap()
}

/// A singlet of constant index, stop at the first surface.
pub fn singlet(r1: f64, r2: f64, t: f64, n: f64, epd: f64, back: f64) -> Lens {
    Lens::from_json(
        &json!({
            "aperture": {"type": "epd", "value": epd}, "wavelengths_nm": [550.0],
            "surfaces": [
                {"radius": r1, "thickness": t, "material": {"n": n}, "stop": true},
                {"radius": r2, "thickness": back, "material": "air"}
            ]
        })
        .to_string(),
    )
    .unwrap()
}

/// The bundled paper-triplet-v1 (python/optix_e2e/bundled/paper-triplet-v1.json, the
/// nominal before issue 17's global search; the engine tests' figures were set on it) with its
/// catalog glasses replaced by the database formulas the Python side resolves them to
/// (refractiveindex.info: PMMA from "organic", N-SF11 from "schott").
pub fn paper_triplet_json() -> Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../python/optix_e2e/bundled/paper-triplet-v1.json");
    let mut v: Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
            .unwrap();
    for s in v["surfaces"].as_array_mut().unwrap() {
        let m = s["material"].clone();
        s["material"] = match m.as_str() {
            Some("PMMA") => {
                json!({"formula": 2, "coefficients": [0.0, 1.1819, 0.011313], "range_um": [0.4368, 1.052], "name": "PMMA (organic)"})
            }
            Some("N-SF11") => {
                json!({"formula": 2, "coefficients": [0.0, 1.73759695, 0.013188707, 0.313747346, 0.0623068142, 1.89878101, 155.23629], "range_um": [0.37, 2.5], "name": "N-SF11 (schott)"})
            }
            Some("air") => json!("air"),
            _ => panic!("paper-triplet: unexpected material {m}"),
        };
    }
    v
}

pub fn paper_triplet() -> Lens {
    Lens::from_json(&paper_triplet_json().to_string()).unwrap()
}

/// The paper triplet as the dataset traces it by default (apertures "auto": no clear apertures,
/// the design's own beam).
#[allow(dead_code)] // not every test binary that includes this module uses it
pub fn paper_triplet_unclipped() -> Lens {
    let mut v = paper_triplet_json();
    for s in v["surfaces"].as_array_mut().unwrap() {
        s.as_object_mut().unwrap().remove("semi_diameter");
    }
    Lens::from_json(&v.to_string()).unwrap()
}

/// The paper-triplet e2e space's 19 parameters (bundled/spaces/paper-triplet-e2e.toml): radii,
/// conics, the three air gaps, and both aspheres' r^2 .. r^10 terms.
#[allow(dead_code)]
pub fn e2e_params() -> Vec<psf_engine::tangent::Param> {
    use psf_engine::tangent::Param;
    let mut p = vec![
        Param::Radius(0),
        Param::Conic(0),
        Param::Radius(1),
        Param::Thickness(1),
        Param::Thickness(3),
        Param::Thickness(4),
        Param::Radius(5),
        Param::Conic(5),
        Param::Radius(6),
    ];
    p.extend((0..5).map(|k| Param::Aspheric(0, k)));
    p.extend((0..5).map(|k| Param::Aspheric(5, k)));
    p
}

/// A lens of the Python suite's fixtures (tests/data/lenses/NAME.json).
pub fn fixture_lens(name: &str) -> Lens {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("../../tests/data/lenses/{name}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Lens::from_json(&text).unwrap()
}
