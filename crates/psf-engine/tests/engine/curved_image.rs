//! A curved image surface: the block kernel and the single-ray trace end each ray on the
//! sphere, where its straight line from the flat image plane meets it; a field's
//! wave-optics analyses use the plane through its chief ray's point (image::flat_at_field).
use crate::common;
use psf_engine::image::flat_at_field;
use psf_engine::{Aiming, Beam, End, System};

#[test]
fn rays_end_on_the_sphere_and_a_fields_plane_goes_through_its_chief_ray() {
    let flat = common::singlet(100.0, -100.0, 1.0, 1.5, 10.0, 99.0);
    let radius = -60.0;
    let mut curved = flat.clone();
    curved.image_curvature = 1.0 / radius;
    let centre_z = curved.image_z + radius;
    let (px, py): (Vec<f64>, Vec<f64>) = (0..25)
        .map(|i| (0.15 * (i % 5) as f64 - 0.3, 0.15 * (i / 5) as f64 - 0.3))
        .unzip();
    for field in [0.0, 5.0, 10.0] {
        let (sf, sc) = (System::new(&flat, 550.0).unwrap(), System::new(&curved, 550.0).unwrap());
        let (bf, bc) = (
            Beam::new(&sf, field, Aiming::Paraxial).unwrap(),
            Beam::new(&sc, field, Aiming::Paraxial).unwrap(),
        );
        let (_, on_plane) = bf.trace_pupil(&px, &py);
        let (launches, on_sphere) = bc.trace_pupil(&px, &py);
        for ((a, b), l) in on_plane.iter().zip(&on_sphere).zip(&launches) {
            assert!(a.ok() && b.ok());
            let r = (b.p - glam::DVec3::new(0.0, 0.0, centre_z)).length();
            assert!(
                (r - radius.abs()).abs() < 1e-9,
                "off the sphere by {}",
                r - radius.abs()
            );
            // the same straight line: b = a + t d, with the optical path grown by t (air)
            let t = b.opl - a.opl;
            assert!((a.p + t * a.d - b.p).length() < 1e-9);
            // the single-ray trace agrees with the block kernel
            let single = sc.trace(l.origin, l.dir, End::Image);
            assert!((single.p - b.p).length() < 1e-12);
        }
        let chief = &on_sphere[12]; // (px, py) = (0, 0)
        let plane = flat_at_field(&curved, field, Aiming::Paraxial).unwrap();
        assert_eq!(plane.image_curvature, 0.0);
        assert!((plane.image_z - chief.p.z).abs() < 1e-12);
    }
    // a flat image is returned as it is
    assert!(matches!(
        flat_at_field(&flat, 5.0, Aiming::Paraxial).unwrap(),
        std::borrow::Cow::Borrowed(_)
    ));
}
