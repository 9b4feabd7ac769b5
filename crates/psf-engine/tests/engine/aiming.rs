//! Real ray aiming: rays land on the stop where they were aimed, and for the Cooke triplet
//! the paraxial pupil is already close to the real one.
use crate::common;
use glam::DVec2;
use psf_engine::{Aiming, Beam, End, System};

#[test]
fn real_aiming_hits_the_stop_where_aimed() {
    let lens = common::cooke();
    let sys = System::new(&lens, 550.0).unwrap();
    for field in [0.0, 14.0, 20.0] {
        let real = Beam::new(&sys, field, Aiming::Real).unwrap();
        let par = Beam::new(&sys, field, Aiming::Paraxial).unwrap();
        let rs = real.stop_radius;
        for (px, py) in [(0.0, 0.0), (0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (0.6, -0.3)] {
            let l = real.launch(px, py);
            let hit = sys.trace(l.origin, l.dir, End::Surface(lens.stop)).p;
            let err = (DVec2::new(hit.x, hit.y) - DVec2::new(px * rs, py * rs)).length();
            let lp = par.launch(px, py);
            let hp = sys.trace(lp.origin, lp.dir, End::Surface(lens.stop)).p;
            eprintln!(
                "field {field} ({px},{py}): real hit ({:.5},{:.5}) paraxial hit ({:.5},{:.5}) stop r {rs:.5}",
                hit.x, hit.y, hp.x, hp.y
            );
            assert!(err < 1e-8, "field {field} pupil ({px},{py}): {err:e} mm from target");
        }
    }
}
