//! Ray paths through every surface (`Beam::trace_path`): the last point is the ordinary
//! image-plane trace bit for bit, every other point lies on its surface, and failed rays
//! stop where they failed.
use crate::common;
use psf_engine::{surface::sag, Aiming, Beam, Lens, Status, System};

/// A fan across the pupil plus a few skew rays, some outside the pupil (vignetted).
fn pupil_points() -> (Vec<f64>, Vec<f64>) {
    let mut px = vec![];
    let mut py = vec![];
    for i in 0..11 {
        px.push(0.0);
        py.push(-1.0 + 0.2 * i as f64);
    }
    for (x, y) in [
        (0.7, 0.3),
        (-0.5, -0.6),
        (1.0, 0.0),
        (0.0, 1.6),
        (0.0, -2.5),
        (1.3, 1.3),
    ] {
        px.push(x);
        py.push(y);
    }
    (px, py)
}

/// Check a lens at a few fields and both aimings; returns (ok rays, failed rays) seen.
fn check(lens: &Lens, fields: &[f64]) -> (usize, usize) {
    let (px, py) = pupil_points();
    let sys = System::new(lens, lens.primary_nm).unwrap();
    let k = lens.surfaces.len();
    let (mut n_ok, mut n_fail) = (0, 0);
    for &field in fields {
        for aiming in [Aiming::Paraxial, Aiming::Real] {
            let beam = Beam::new(&sys, field, aiming).unwrap();
            let path = beam.trace_path(&px, &py).unwrap();
            let plain = beam.trace_pupil_soa(&px, &py);
            assert_eq!(path.points, k + 1);
            assert_eq!(path.image.status, plain.status);
            assert_eq!(path.image.surface, plain.surface);
            for j in 0..px.len() {
                let pt = |i: usize| &path.position[(j * (k + 1) + i) * 3..(j * (k + 1) + i) * 3 + 3];
                let last = path.last[j];
                if plain.status[j] == Status::Ok as u8 {
                    n_ok += 1;
                    assert_eq!(
                        last, k as i32,
                        "field {field} ray {j}: reached the image, last point {last}"
                    );
                    // Bit for bit, not just close.
                    for c in 0..3 {
                        assert_eq!(
                            pt(k)[c].to_bits(),
                            plain.position[3 * j + c].to_bits(),
                            "field {field} {aiming:?} ray {j} coord {c}"
                        );
                    }
                } else {
                    n_fail += 1;
                    let s = plain.surface[j];
                    let expect = match Status::from_code(plain.status[j]) {
                        Status::Clipped | Status::Tir => s,
                        _ => s - 1,
                    };
                    assert_eq!(
                        last, expect,
                        "field {field} ray {j}: status {} at surface {s}",
                        plain.status[j]
                    );
                }
                for i in 0..=k {
                    let p = pt(i);
                    if i as i32 > last {
                        assert!(
                            p.iter().all(|&v| v == 0.0),
                            "ray {j}: point {i} after the last is not zero"
                        );
                        continue;
                    }
                    assert!(p.iter().all(|v| v.is_finite()));
                    let (z0, rho) = (
                        if i < k { lens.surfaces[i].z } else { lens.image_z },
                        p[0] * p[0] + p[1] * p[1],
                    );
                    let want = if i < k {
                        z0 + sag(&lens.surfaces[i], rho).unwrap()
                    } else {
                        z0
                    };
                    assert!(
                        (p[2] - want).abs() < 1e-12,
                        "field {field} ray {j} surface {i}: z {} vs sag {want} ({:e})",
                        p[2],
                        p[2] - want
                    );
                }
            }
        }
    }
    (n_ok, n_fail)
}

#[test]
fn cooke_paths_end_on_the_image_trace_and_lie_on_surfaces() {
    let lens = common::cooke();
    let (ok, fail) = check(&lens, &[0.0, 14.0, 20.0]);
    eprintln!("cooke: {ok} rays reached the image, {fail} failed");
    assert!(ok > 60 && fail > 0, "the test needs both kinds: {ok} ok, {fail} failed");
}

#[test]
fn aspheric_lens_with_apertures_clips_where_it_should() {
    // Even aspheres, a conic and clear apertures: rays outside the pupil are clipped, and
    // keep their (outside-aperture) hit point on the surface that stopped them.
    let lens = Lens::from_json(
        r#"{"aperture": {"type": "epd", "value": 8}, "wavelengths_nm": [550],
            "surfaces": [
              {"radius": 14, "conic": -0.6, "aspheric": {"a4": -2e-5, "a6": 1e-7}, "thickness": 5, "material": {"n": 1.75}, "semi_diameter": 6},
              {"radius": "inf", "thickness": 2, "material": "air", "semi_diameter": 6},
              {"radius": 25, "conic": 0.5, "thickness": 3, "material": {"n": 1.6}, "stop": true, "semi_diameter": 4.5},
              {"radius": -40, "aspheric": {"a4": 3e-5}, "thickness": 18, "material": "air", "semi_diameter": 5}]}"#,
    )
    .unwrap();
    let (px, py) = pupil_points();
    let sys = System::new(&lens, 550.0).unwrap();
    let path = Beam::new(&sys, 10.0, Aiming::Paraxial)
        .unwrap()
        .trace_path(&px, &py)
        .unwrap();
    let clipped = (0..px.len())
        .filter(|&j| path.image.status[j] == Status::Clipped as u8)
        .count();
    assert!(
        clipped >= 2,
        "expected clipped rays, got statuses {:?}",
        path.image.status
    );
    for j in 0..px.len() {
        if path.image.status[j] == Status::Clipped as u8 {
            let i = path.last[j] as usize;
            let p = &path.position[(j * 5 + i) * 3..(j * 5 + i) * 3 + 3];
            let sd = lens.surfaces[i].semi_diameter.unwrap();
            assert!(
                p[0].hypot(p[1]) > sd,
                "clipped ray {j} at surface {i} lies inside the aperture"
            );
        }
    }
    check(&lens, &[0.0, 10.0]);
}
