//! The vectorized block kernel (trace_many, trace_blocks) and the single-ray trace share
//! their geometry code: they must agree to the last bit, statuses and failing surfaces
//! included, for every surface kind and every way a ray can fail.
use crate::common;
use glam::DVec3;
use psf_engine::{End, Lens, RayState, Status, System};
use serde_json::json;

/// Plane, conic and even-asphere surfaces, clear apertures, a dense glass that gives TIR
/// at steep incidence, and an image semi-diameter. The last surface is an asphere too, so
/// that rays that failed earlier reach the block's lockstep asphere iteration (which skips
/// them) beside live ones.
fn mixed_lens() -> Lens {
    Lens::from_json(
        &json!({
            "aperture": {"type": "epd", "value": 10.0}, "wavelengths_nm": [550.0],
            "surfaces": [
                {"radius": 12.0, "conic": -0.6, "aspheric": {"a4": -2e-5, "a6": 1e-8}, "thickness": 6.0, "material": {"n": 1.9}, "semi_diameter": 8.0},
                {"radius": "inf", "thickness": 2.0, "material": "air", "semi_diameter": 8.0},
                {"radius": 25.0, "conic": 0.5, "thickness": 3.0, "material": {"n": 1.6}, "stop": true, "semi_diameter": 6.0},
                {"radius": -40.0, "aspheric": {"a4": 1e-5}, "thickness": 35.0, "material": "air", "semi_diameter": 7.0}
            ],
            "image": {"semi_diameter": 12.0}
        })
        .to_string(),
    )
    .unwrap()
}

fn rays(n: usize, max_deg: f64, reach: f64) -> (Vec<DVec3>, Vec<DVec3>) {
    // A deterministic spread of origins and directions, some far outside the aperture.
    let (mut o, mut d) = (vec![], vec![]);
    for i in 0..n {
        let u = (i as f64 * 0.618_033_988_75).fract();
        let v = (i as f64 * 0.414_213_562_37).fract();
        let w = (i as f64 * 0.732_050_807_57).fract();
        let a = (w * 2.0 - 1.0) * max_deg.to_radians();
        let b = (u - 0.5) * 0.3 * max_deg.to_radians();
        d.push(DVec3::new(b.sin(), a.sin(), (1.0 - b.sin().powi(2) - a.sin().powi(2)).sqrt()).normalize());
        o.push(DVec3::new((u * 2.0 - 1.0) * reach, (v * 2.0 - 1.0) * reach, -5.0));
    }
    (o, d)
}

fn same(a: &RayState, b: &RayState) -> bool {
    a.status == b.status && a.surface == b.surface && a.p == b.p && a.d == b.d && a.opl.to_bits() == b.opl.to_bits()
}

fn check(lens: &Lens, max_deg: f64, reach: f64) -> [usize; 5] {
    let sys = System::new(lens, 550.0).unwrap();
    let (o, d) = rays(5000, max_deg, reach);
    let many = sys.trace_many(&o, &d);
    let mut counts = [0; 5];
    for (k, r) in many.iter().enumerate() {
        let one = sys.trace(o[k], d[k], End::Image);
        assert!(same(r, &one), "ray {k}: block {r:?} vs single {one:?}");
        counts[r.status as usize] += 1;
        if r.ok() {
            assert!(r.p.is_finite() && r.d.is_finite() && r.opl.is_finite());
        } else {
            assert_eq!(r.p, DVec3::ZERO, "failed rays carry no coordinates");
        }
    }
    counts
}

#[test]
fn block_kernel_matches_single_ray_trace_bit_for_bit() {
    let counts = check(&common::cooke(), 25.0, 12.0);
    assert!(counts[0] > 1000, "{counts:?}");
    let counts = check(&mixed_lens(), 60.0, 10.0);
    // Every outcome occurs, so every code path of the kernel was compared.
    for (st, c) in [Status::Ok, Status::Missed, Status::Clipped, Status::Tir]
        .iter()
        .zip(counts)
    {
        assert!(c > 0, "no {st:?} rays: {counts:?}");
    }
}

#[test]
fn invalid_input_is_flagged_not_traced() {
    let lens = common::cooke();
    let sys = System::new(&lens, 550.0).unwrap();
    let o = vec![
        DVec3::new(0.0, 0.0, -5.0),
        DVec3::new(f64::NAN, 0.0, -5.0),
        DVec3::new(0.0, 1.0, -5.0),
    ];
    let d = vec![DVec3::Z, DVec3::Z, DVec3::new(0.0, 0.0, 2.0)];
    let r = sys.trace_many(&o, &d);
    assert_eq!(
        [r[0].status, r[1].status, r[2].status],
        [Status::Ok, Status::Invalid, Status::Invalid]
    );
}

#[test]
fn flat_pupil_trace_matches_ray_states() {
    use psf_engine::{Aiming, Beam};
    let lens = common::cooke();
    let sys = System::new(&lens, 486.1).unwrap();
    let (px, py): (Vec<f64>, Vec<f64>) = (0..300)
        .map(|i| ((i as f64 * 0.37).sin() * 1.1, (i as f64 * 0.53).cos() * 1.1))
        .unzip();
    for aiming in [Aiming::Paraxial, Aiming::Real] {
        let beam = Beam::new(&sys, 20.0, aiming).unwrap();
        let (launches, states) = beam.trace_pupil(&px, &py);
        let flat = beam.trace_pupil_soa(&px, &py);
        for (k, r) in states.iter().enumerate() {
            assert_eq!(flat.status[k], r.status as u8);
            assert_eq!(flat.surface[k], r.surface);
            assert_eq!(&flat.origin[3 * k..3 * k + 3], &launches[k].origin.to_array());
            assert_eq!(&flat.position[3 * k..3 * k + 3], &r.p.to_array());
            assert_eq!(&flat.direction[3 * k..3 * k + 3], &r.d.to_array());
            assert_eq!(flat.opl[k], r.opl);
        }
    }
}

/// A surface that lies behind the ray (here: a ray starting inside the first element,
/// past surface 1) is a miss at that surface, in both the single-ray and block paths.
#[test]
fn surface_behind_the_ray_is_a_miss() {
    let lens = common::cooke();
    let sys = System::new(&lens, 550.0).unwrap();
    let (o, d) = (DVec3::new(0.0, 1.0, 2.0), DVec3::Z);
    let one = sys.trace(o, d, End::Image);
    assert_eq!((one.status, one.surface), (Status::Missed, 0), "{one:?}");
    let many = sys.trace_many(&[o, DVec3::new(0.0, 1.0, -5.0)], &[d, d]);
    assert_eq!((many[0].status, many[0].surface), (Status::Missed, 0));
    assert_eq!(many[1].status, Status::Ok);
}
