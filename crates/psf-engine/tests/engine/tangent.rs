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
fn tangents_through_spheres_a_radius_and_an_aspheric_term_a_surface_lacks() {
    let lens = common::cooke();
    let params = [
        Param::Curvature(1),
        Param::Thickness(2),
        Param::Aspheric(3, 1), // the Cooke triplet has no aspheric terms: a4 = 0 moved
        Param::Curvature(5),
        Param::Radius(4), // the spaces' radius: the curvature's tangent times -c^2
    ];
    let steps = [1e-7, 1e-6, 1e-8, 1e-7, 1e-5];
    let (err, k) = worst_error::<5>(&lens, &params, &steps, &[]);
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

/// The fast FFT PSF's coarse-ray data for a lens, by the kernel alone (what psf/fast.rs
/// computes): W (waves) and (L, M) of each pupil point, the chief image point and radius.
fn pupil_data(lens: &Lens, wl: f64, field: f64, px: &[f64], py: &[f64]) -> Vec<f64> {
    let sys = System::new(lens, wl).unwrap();
    let beam = Beam::new(&sys, field, Aiming::Paraxial).unwrap();
    let c = beam.launch(0.0, 0.0);
    let chief = sys.trace(c.origin, c.dir, End::Image);
    assert!(chief.ok());
    let z_xp = lens.image_z + beam.par.exit_pupil_z;
    let radius = ((z_xp - chief.p.z) / chief.d.z * chief.d).length();
    let n_img = sys.image_index();
    let chief_sphere_opl = chief.opl + beam.wavefront_offset(c.origin) - n_img * radius;
    let mut out = vec![chief.p.x, chief.p.y, chief.p.z, radius];
    for (&x, &y) in px.iter().zip(py) {
        let l = beam.launch(x, y);
        let r = sys.trace(l.origin, l.dir, End::Image);
        assert!(r.ok());
        let v = r.p - chief.p;
        let vd = v.dot(r.d);
        let tt = -vd - (vd * vd - v.length_squared() + radius * radius).sqrt();
        out.push((r.opl + beam.wavefront_offset(l.origin) + n_img * tt - chief_sphere_opl) / (wl * 1e-6));
        let s = r.p + tt * r.d;
        out.push((chief.p.x - s.x) / radius);
        out.push((chief.p.y - s.y) / radius);
    }
    out
}

#[test]
fn the_coarse_pupils_wavefront_and_directions_have_the_tangents_of_their_differences() {
    let lens = common::paper_triplet();
    let params = [
        Param::Curvature(0),
        Param::Aspheric(0, 0), // a2: the paraxial curvature moves too (EFL, EPD at f/4.4, pupils)
        Param::Aspheric(0, 1),
        Param::Thickness(1),
        Param::Conic(5),
        Param::Curvature(6),
        Param::Thickness(4), // the stop's gap: the entrance pupil moves
        Param::Thickness(6),
    ];
    let steps = [1e-7, 1e-8, 1e-9, 1e-6, 1e-6, 1e-7, 1e-6, 1e-6];
    the_coarse_pupil_along(&lens, &params, &steps);
    // the aperture: the f-number scales the pupil (and so W, L and M)
    the_coarse_pupil_along(&lens, &[Param::FNumber, Param::Curvature(2)], &[1e-5, 1e-7]);
}

fn the_coarse_pupil_along<const N: usize>(lens: &Lens, params: &[Param; N], steps: &[f64; N]) {
    use psf_engine::tangent::pupil_tangents;
    let lens = lens.clone();
    let (px, py) = (vec![0.3, 0.0, 0.6, 0.2, 0.0], vec![0.0, 0.5, -0.4, 0.85, -0.9]);
    let wl = 550.0;
    let sys = System::new(&lens, wl).unwrap();
    let mut worst = 0.0f64;
    for field in [0.0, 9.0, lens.max_field_deg()] {
        let t = pupil_tangents::<N>(&sys, params, field, &px, &py)
            .unwrap()
            .expect("every ray traced");
        let mut tan: Vec<[f64; N]> = t.chief.iter().map(|c| c.d).collect();
        tan.push(t.radius.d);
        for i in 0..px.len() {
            tan.extend([t.w[i].d, t.l[i].d, t.m[i].d]);
        }
        let base = pupil_data(&lens, wl, field, &px, &py);
        assert_eq!(base.len(), tan.len());
        assert!((t.w[1].v - base[4 + 3]).abs() < 1e-6 && (t.radius.v - base[3]).abs() < 1e-9);
        for (k, (&p, &h)) in params.iter().zip(steps).enumerate() {
            let (a, b) = (
                pupil_data(&perturbed(&lens, p, h).unwrap(), wl, field, &px, &py),
                pupil_data(&perturbed(&lens, p, -h).unwrap(), wl, field, &px, &py),
            );
            // each quantity against its own difference: within 1e-5 of the largest of its kind,
            // plus the difference's own round-off (the kind's typical size x 1e-16 / h; W is a
            // difference of optical paths of ~1e5 waves)
            let kinds: [(&str, Vec<usize>, f64); 5] = [
                ("chief point", (0..3).collect(), 1e-14),
                ("radius", vec![3], 1e-14),
                ("W", (0..px.len()).map(|i| 4 + 3 * i).collect(), 1e-10),
                ("L", (0..px.len()).map(|i| 5 + 3 * i).collect(), 1e-16),
                ("M", (0..px.len()).map(|i| 6 + 3 * i).collect(), 1e-16),
            ];
            for (kind, idx, noise) in kinds {
                let fd: Vec<f64> = idx.iter().map(|&i| (a[i] - b[i]) / (2.0 * h)).collect();
                let scale = fd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                let tol = 1e-5 * scale + 10.0 * noise / h;
                for (f, &i) in fd.iter().zip(&idx) {
                    let err = (f - tan[i][k]).abs();
                    assert!(
                        err <= tol,
                        "{p:?} at {field} deg, {kind} [{i}]: {} against {f} (tol {tol:e})",
                        tan[i][k]
                    );
                    worst = worst.max(err / scale.max(1e-300));
                }
            }
        }
    }
    assert!(worst > 0.0);
}
