//! Forward-mode tangents of a traced ray (`tangent::trace_tangents`) against central
//! differences of the kernel's own trace of the perturbed lens (`tangent::perturbed`), the
//! launch held fixed: aspheric, conic, spherical and plane surfaces, thicknesses (every later
//! vertex and the image plane move), at three fields.
use crate::common;
use psf_engine::tangent::{perturbed, trace_tangents, Param};
use psf_engine::{Aiming, Beam, End, Lens, System};

/// The largest |tangent - central difference| over the image point, direction and optical
/// path, relative to the largest |difference| of that parameter (and the worst parameter);
/// the `inert` parameters move no ray (their tangents must then be zero too).
fn worst_error<const N: usize>(lens: &Lens, params: &[Param], steps: &[f64], inert: &[Param]) -> (f64, usize) {
    let wl = lens.primary_nm;
    let sys = System::new(lens, wl).unwrap();
    let mut worst = (0.0f64, 0usize);
    let mut checked = 0;
    let mut moved = vec![false; params.len()];
    for field in [0.0, 0.6 * lens.max_field_deg(), lens.max_field_deg()] {
        let beam = Beam::new(&sys, field, Aiming::Paraxial).unwrap();
        for (px, py) in [(0.0, 0.0), (0.5, 0.3), (0.0, -0.75), (-0.6, 0.45)] {
            let l = beam.launch(px, py);
            let Some(t) = trace_tangents::<N>(&sys, params, l.origin, l.dir) else {
                continue;
            };
            checked += 1;
            for (k, (&p, &h)) in params.iter().zip(steps).enumerate() {
                let trace = |s: f64| {
                    let lp = perturbed(lens, p, s * h).unwrap();
                    let r = System::new(&lp, wl).unwrap().trace(l.origin, l.dir, End::Image);
                    assert!(r.ok(), "{p:?} {s}: {r:?}");
                    [r.p.x, r.p.y, r.p.z, r.d.x, r.d.y, r.d.z, r.opl]
                };
                let (a, b) = (trace(1.0), trace(-1.0));
                let fd: Vec<f64> = a.iter().zip(&b).map(|(a, b)| (a - b) / (2.0 * h)).collect();
                let tan = [t.p[0], t.p[1], t.p[2], t.d[0], t.d[1], t.d[2], t.opl].map(|x| x.d[k]);
                // relative to the largest derivative (an axial ray that a curvature does not
                // move: absolute, at a scale of 1)
                let scale = fd.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(1.0);
                let err = fd.iter().zip(&tan).fold(0.0f64, |m, (f, t)| m.max((f - t).abs())) / scale;
                moved[k] |= fd.iter().any(|x| x.abs() > 1e-3);
                if err > worst.0 {
                    worst = (err, k);
                }
            }
        }
    }
    assert!(checked >= 10, "only {checked} rays traced");
    for (p, m) in params.iter().zip(&moved) {
        assert_eq!(*m, !inert.contains(p), "{p:?} moves a ray: {m}");
    }
    worst
}

#[test]
fn tangents_of_a_ray_through_an_aspheric_triplet_match_central_differences() {
    let lens = common::paper_triplet();
    let stop = lens.stop;
    assert!(lens.surfaces[stop].curvature == 0.0 && lens.surfaces[0].has_asphere());
    let params = [
        Param::Curvature(0),
        Param::Conic(0),
        Param::Aspheric(0, 1),
        Param::Thickness(0),
        Param::Curvature(stop), // a plane in air: bending it moves no ray (tangent 0)
        Param::Conic(2),        // a sphere's conic
        Param::Aspheric(5, 2),
        Param::Thickness(6), // the back focus: the image plane moves
    ];
    let steps = [1e-7, 1e-6, 1e-9, 1e-6, 1e-6, 1e-6, 1e-9, 1e-6];
    let (err, k) = worst_error::<8>(&lens, &params, &steps, &[Param::Curvature(stop)]);
    assert!(err < 1e-5, "{:?}: relative error {err:e}", params[k]);
}

#[test]
fn tangents_through_spheres_and_an_aspheric_term_a_surface_lacks() {
    let lens = common::cooke();
    let params = [
        Param::Curvature(1),
        Param::Thickness(2),
        Param::Aspheric(3, 1), // the Cooke triplet has no aspheric terms: a4 = 0 moved
        Param::Curvature(5),
    ];
    let steps = [1e-7, 1e-6, 1e-8, 1e-7];
    let (err, k) = worst_error::<4>(&lens, &params, &steps, &[]);
    assert!(err < 1e-5, "{:?}: relative error {err:e}", params[k]);
}

#[test]
fn a_ray_the_kernel_does_not_bring_to_the_image_has_no_tangents() {
    let lens = common::paper_triplet();
    let sys = System::new(&lens, lens.primary_nm).unwrap();
    let beam = Beam::new(&sys, 0.0, Aiming::Paraxial).unwrap();
    let l = beam.launch(0.0, 1.5); // outside the stop: clipped
    assert!(!sys.trace(l.origin, l.dir, End::Image).ok());
    assert!(trace_tangents::<1>(&sys, &[Param::Curvature(0)], l.origin, l.dir).is_none());
}
