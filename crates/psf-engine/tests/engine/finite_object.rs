//! A finite object distance: conjugates and magnification against Newton's equations, the
//! limit of a far object against the object at infinity, the object-space NA, and the cos^4
//! law of a thin lens at finite conjugates.

use crate::common;
use psf_engine::aim::Aiming;
use psf_engine::spot::{relative_illumination_from, trace_spot};
use psf_engine::{paraxial, Beam, End, Lens, System};
use serde_json::{json, Value};

fn with_object(mut v: Value, d: f64) -> Lens {
    v["object_distance"] = json!(d);
    Lens::from_json(&v.to_string()).unwrap()
}

#[test]
fn conjugates_and_magnification_follow_newton() {
    let base = common::cooke_json();
    let inf = paraxial(&common::cooke(), 550.0).unwrap();
    let (f, ffl, bfl) = (inf.efl, inf.ffl, inf.bfl);
    for d in [150.0, 400.0, 2000.0] {
        let lens = with_object(base.clone(), d);
        let p = paraxial(&lens, 550.0).unwrap();
        assert_eq!(
            (p.efl, p.bfl, p.ffl, p.entrance_pupil_z),
            (f, bfl, ffl, inf.entrance_pupil_z)
        );
        // x x' = -f^2: the object lies d + ffl before the front focal point
        let x_img = f * f / (d + ffl);
        let last = lens.surfaces.last().unwrap().z;
        let want = last + bfl + x_img - lens.image_z;
        assert!(
            (p.back_focus_shift - want).abs() < 1e-9 * want.abs().max(1.0),
            "d {d}: {} vs {want}",
            p.back_focus_shift
        );
        // m = -f / x: the object point of the largest field sits at -L tan(field)
        let l = d + inf.entrance_pupil_z;
        assert!((p.object_to_pupil - l).abs() < 1e-12);
        let h = f * l * lens.max_field_deg().to_radians().tan() / (d + ffl);
        assert!(
            (p.image_height / h - 1.0).abs() < 1e-10,
            "d {d}: {} vs {h}",
            p.image_height
        );
    }
}

#[test]
fn real_chief_ray_meets_the_paraxial_image_of_a_near_point() {
    // image plane moved onto the paraxial image of an object 300 mm away
    let mut v = common::cooke_json();
    v["object_distance"] = json!(300.0);
    let p = paraxial(&Lens::from_json(&v.to_string()).unwrap(), 550.0).unwrap();
    let n = v["surfaces"].as_array().unwrap().len();
    let t = v["surfaces"][n - 1]["thickness"].as_f64().unwrap();
    v["surfaces"][n - 1]["thickness"] = json!(t + p.back_focus_shift);
    v["fields_deg"] = json!([0.0, 0.01]);
    let lens = Lens::from_json(&v.to_string()).unwrap();
    let p = paraxial(&lens, 550.0).unwrap();
    assert!(p.back_focus_shift.abs() < 1e-9);
    let sys = System::new(&lens, 550.0).unwrap();
    let beam = Beam::new(&sys, 0.01, Aiming::Paraxial).unwrap();
    let c = beam.launch(0.0, 0.0);
    // the chief ray leaves the object point at the field angle
    assert!((c.dir.y - 0.01f64.to_radians().sin()).abs() < 1e-15);
    let r = sys.trace(c.origin, c.dir, End::Image);
    assert!(r.ok());
    assert!(
        (r.p.y / p.image_height - 1.0).abs() < 1e-5,
        "{} vs {}",
        r.p.y,
        p.image_height
    );
    // a small pupil focuses there: the spot shrinks with the aperture (spherical aberration)
    let spot = trace_spot(&lens, 0.0, 550.0, 8, Aiming::Paraxial).unwrap();
    let rms = (spot
        .x
        .iter()
        .zip(&spot.y)
        .zip(&spot.w)
        .map(|((x, y), w)| w * (x * x + y * y))
        .sum::<f64>()
        / spot.flux)
        .sqrt();
    assert!(rms < 0.05, "on-axis RMS spot {rms} mm");
}

#[test]
fn a_far_object_is_the_object_at_infinity() {
    let base = common::cooke_json();
    let inf = common::cooke();
    let far = with_object(base, 1e9);
    for (f, wl) in [(0.0, 550.0), (14.0, 480.0), (20.0, 650.0)] {
        for aiming in [Aiming::Paraxial, Aiming::Real] {
            let a = trace_spot(&inf, f, wl, 12, aiming).unwrap();
            let b = trace_spot(&far, f, wl, 12, aiming).unwrap();
            assert_eq!(a.x.len(), b.x.len());
            let dx =
                a.x.iter()
                    .zip(&b.x)
                    .chain(a.y.iter().zip(&b.y))
                    .map(|(p, q)| (p - q).abs())
                    .fold(0.0, f64::max);
            assert!(dx < 1e-6, "{f} deg {aiming:?}: image points differ by {dx} mm");
            assert!((a.flux / a.w.len() as f64 - b.flux / b.w.len() as f64).abs() < 1e-6 * a.flux / a.w.len() as f64);
        }
        let ri_a = relative_illumination_from(&inf, f, wl, Aiming::Paraxial, None).unwrap();
        let ri_b = relative_illumination_from(&far, f, wl, Aiming::Paraxial, None).unwrap();
        assert!((ri_a - ri_b).abs() < 1e-6, "{f} deg: RI {ri_a} vs {ri_b}");
    }
}

#[test]
fn object_na_is_the_sine_of_the_marginal_ray() {
    for (na, d) in [(0.1, 40.0), (0.25, 0.0)] {
        let mut v = json!({
            "aperture": {"type": "object_na", "value": na}, "wavelengths_nm": [550.0], "object_distance": d,
            "surfaces": [
                {"radius": "inf", "thickness": 8.0, "material": "air"},
                {"radius": "inf", "thickness": 4.0, "material": {"n": 1.6}, "stop": true},
                {"radius": -12.0, "thickness": 20.0, "material": "air"}
            ]
        });
        let lens = Lens::from_json(&v.to_string()).unwrap();
        let sys = System::new(&lens, 550.0).unwrap();
        for aiming in [Aiming::Paraxial, Aiming::Real] {
            let beam = Beam::new(&sys, 0.0, aiming).unwrap();
            let m = beam.launch(0.0, 1.0);
            assert!((m.dir.y - na).abs() < 1e-9, "NA {na}, {aiming:?}: sin u = {}", m.dir.y);
        }
        // an object at infinity has no object-space NA: one clear error
        v["object_distance"] = json!("inf");
        let e = Lens::from_json(&v.to_string()).unwrap_err().to_string();
        assert!(e.contains("object_na") && e.contains("object_distance"), "{e}");
    }
    let e = Lens::from_json(
        &json!({"aperture": {"type": "epd", "value": 1}, "object_distance": -5,
        "surfaces": [{"radius": 20, "thickness": 30, "material": "air", "stop": true}]})
        .to_string(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("object_distance") && e.contains(">= 0"), "{e}");
}

#[test]
fn thin_lens_at_finite_conjugates_follows_cos4() {
    // f = 50 mm plano-convex, stop on the lens, object 150 mm away, image at its conjugate
    // (75 mm): the chief ray passes the thin lens undeviated, so the image-side angle equals
    // the field angle and the irradiance falls as cos^4, at focus and 1 mm off it.
    let lens = common::singlet(25.0, 1e18, 0.02, 1.5, 1.0, 75.0);
    let mut v: Value = json!({
        "aperture": {"type": "epd", "value": 1.0}, "wavelengths_nm": [550.0], "object_distance": 150.0,
        "surfaces": [
            {"radius": 25.0, "thickness": 0.02, "material": {"n": 1.5}, "stop": true},
            {"radius": 1e18, "thickness": 75.0, "material": "air"}
        ]
    });
    let p = paraxial(&Lens::from_json(&v.to_string()).unwrap(), 550.0).unwrap();
    assert!(p.back_focus_shift.abs() < 0.05, "{}", p.back_focus_shift);
    drop(lens);
    for dz in [0.0, 1.0] {
        v["surfaces"][1]["thickness"] = json!(75.0 + p.back_focus_shift + dz);
        let lens = Lens::from_json(&v.to_string()).unwrap();
        for f in [10.0f64, 20.0, 30.0] {
            let ri = relative_illumination_from(&lens, f, 550.0, Aiming::Paraxial, None).unwrap();
            let c4 = f.to_radians().cos().powi(4);
            assert!((ri / c4 - 1.0).abs() < 2e-3, "dz {dz}, {f} deg: {ri} vs cos^4 {c4}");
        }
    }
}
