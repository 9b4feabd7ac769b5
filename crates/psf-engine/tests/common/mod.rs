//! Shared helpers: the classic Cooke triplet of ../shared/reference (computed with another
//! tool), converted to our prescription format, and small synthetic lenses.
#![allow(dead_code)]

use psf_engine::Lens;
use serde_json::{json, Value};
use std::path::PathBuf;

pub fn reference_dir() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/reference");
    assert!(p.join("cooke_triplet.json").exists(), "reference data missing: expected {} (shared/ beside the repo)", p.display());
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
            let kind: u64 = m["formula"].as_str().unwrap().trim_start_matches("formula ").parse().unwrap();
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
