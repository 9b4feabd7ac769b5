//! Odd-power aspheric terms (OpticStudio's odd asphere): an axicon's cone deflects every
//! ray parallel to the axis by the same closed-form angle, and its sag matches a1 r + a3 r^3.

use glam::DVec3;
use psf_engine::surface::sag;
use psf_engine::{End, Lens, System};
use serde_json::json;

#[test]
fn an_axicon_deflects_parallel_rays_by_snells_angle() {
    let n = 1.46;
    for alpha_deg in [5.0f64, 10.0, 20.0] {
        let a = alpha_deg.to_radians();
        // flat front, cone z = -tan(a) r at the back: a ray parallel to the axis meets the
        // cone at incidence a inside the glass and leaves at asin(n sin a) - a to the axis
        let lens = Lens::from_json(
            &json!({
                "aperture": {"type": "epd", "value": 20.0}, "wavelengths_nm": [550.0],
                "surfaces": [
                    {"radius": "inf", "thickness": 5.0, "material": {"n": n}, "stop": true},
                    {"radius": "inf", "aspheric": {"a1": -a.tan()}, "thickness": 50.0, "material": "air"}
                ]
            })
            .to_string(),
        )
        .unwrap();
        let sys = System::new(&lens, 550.0).unwrap();
        let want = (n * a.sin()).asin() - a;
        for h in [0.5, 3.0, 9.0] {
            let r = sys.trace(DVec3::new(0.0, h, -10.0), DVec3::Z, End::Image);
            assert!(r.ok());
            let got = (-r.d.y).atan2(r.d.z);
            assert!((got - want).abs() < 1e-12, "{alpha_deg} deg, h {h}: {got} vs {want}");
        }
        // the ray on the axis meets the apex: taken along the axis, not NaN
        let r = sys.trace(DVec3::new(0.0, 0.0, -10.0), DVec3::Z, End::Image);
        assert!(r.ok() && r.d.z == 1.0);
    }
}

#[test]
fn odd_sag_is_the_polynomial_in_r() {
    let lens = Lens::from_json(&json!({
        "aperture": {"type": "epd", "value": 2.0}, "wavelengths_nm": [550.0],
        "surfaces": [
            {"radius": 40.0, "aspheric": {"a1": 0.01, "a3": -2e-4, "a4": 1e-6, "a7": 3e-9}, "thickness": 3.0, "material": {"n": 1.5}, "stop": true},
            {"radius": "inf", "thickness": 60.0, "material": "air"}
        ]
    }).to_string()).unwrap();
    let s = &lens.surfaces[0];
    for r in [0.0f64, 0.7, 2.5, 6.0] {
        let c = 1.0 / 40.0;
        let want = c * r * r / (1.0 + (1.0 - c * c * r * r).sqrt()) + 0.01 * r - 2e-4 * r.powi(3)
            + 1e-6 * r.powi(4)
            + 3e-9 * r.powi(7);
        assert!((sag(s, r * r).unwrap() - want).abs() < 1e-15, "r {r}");
    }
    let e = Lens::from_json(
        &json!({"aperture": {"type": "epd", "value": 2.0},
        "surfaces": [{"radius": 40.0, "aspheric": {"a9": 1e-9}, "thickness": 3.0, "material": "air", "stop": true}]})
        .to_string(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("a9") && e.contains("unknown"), "{e}");
}
