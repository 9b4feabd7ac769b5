//! The engine against independent reference data (optiland 0.6.3, cross-checked with
//! rayoptics) for the classic Cooke triplet: indices, first-order data, golden rays.

use crate::common;
use glam::DVec3;
use psf_engine::{paraxial, Aiming, Beam, End, System};

#[test]
fn glass_indices_match_reference() {
    let r = common::read_json("cooke_triplet.json");
    let lens = common::cooke();
    for wl in ["0.4800", "0.5500", "0.6500"] {
        let n = lens.indices(wl.parse::<f64>().unwrap() * 1e3).unwrap();
        for (i, s) in r["surfaces"]
            .as_array()
            .unwrap()
            .iter()
            .enumerate()
            .filter(|(_, s)| s["role"] == "refracting")
        {
            let want = s["material_after"]["n"][wl].as_f64().unwrap();
            assert!(
                (n[i] - want).abs() < 1e-12,
                "surface {i} at {wl} um: {} vs {want}",
                n[i]
            );
        }
    }
}

#[test]
fn first_order_matches_reference() {
    let f = &common::read_json("cooke_triplet_reference.json")["first_order"];
    let p = paraxial(&common::cooke(), 550.0).unwrap();
    let rel = |a: f64, key: &str| {
        let b = f[key].as_f64().unwrap();
        let e = ((a - b) / b).abs();
        assert!(e < 1e-9, "{key}: {a} vs {b} (rel {e:e})");
    };
    rel(p.efl, "efl_mm");
    rel(p.bfl, "bfl_mm_last_vertex_to_paraxial_focus");
    rel(p.epd, "epd_mm");
    rel(p.f_number, "fno_paraxial");
    rel(p.entrance_pupil_z, "entrance_pupil_pos_mm_rel_first_surface");
    rel(p.xpd, "xpd_mm");
    rel(p.exit_pupil_z, "exit_pupil_pos_mm_rel_image_plane");
    rel(p.total_track, "total_track_first_vertex_to_image_mm");
    rel(p.image_height, "paraxial_image_height_f_tan_mm");
    rel(p.back_focus_shift, "back_focal_point_rel_image_plane_mm");
}

#[test]
fn golden_rays_intercepts_and_opl_within_1e9_mm() {
    let g = common::read_json("cooke_triplet_golden_rays.json");
    let lens = common::cooke();
    let mut worst = (0.0f64, 0.0f64);
    for r in g["rays"].as_array().unwrap() {
        let wl = r["wl_um"].as_f64().unwrap() * 1e3;
        let sys = System::new(&lens, wl).unwrap();
        let v = |k: &str, i: usize| r[k][i].as_f64().unwrap();
        let o = DVec3::new(v("start", 0), v("start", 1), v("start", 2));
        let d = DVec3::new(v("start", 3), v("start", 4), v("start", 5));
        let out = sys.trace(o, d.normalize(), End::Image);
        assert!(out.ok(), "ray {r} failed: {out:?}");
        let want = DVec3::new(v("image_xyz", 0), v("image_xyz", 1), v("image_xyz", 2));
        let dp = (out.p - want).length();
        let dopl = (out.opl - r["opl_from_start_mm"].as_f64().unwrap()).abs();
        let dd = (out.d - DVec3::new(v("image_LMN", 0), v("image_LMN", 1), v("image_LMN", 2))).length();
        assert!(
            dp < 1e-9 && dopl < 1e-9 && dd < 1e-9,
            "ray Hy={} Px={} Py={} wl={wl}: dp={dp:e} dopl={dopl:e} dd={dd:e}",
            r["Hy"],
            r["Px"],
            r["Py"]
        );
        worst = (worst.0.max(dp), worst.1.max(dopl));
        // Our paraxial aiming must launch the same ray: compare image intercepts.
        let field = r["Hy"].as_f64().unwrap() * 20.0;
        let beam = Beam::new(&sys, field, Aiming::Paraxial).unwrap();
        let l = beam.launch(r["Px"].as_f64().unwrap(), r["Py"].as_f64().unwrap());
        let ours = sys.trace(l.origin, l.dir, End::Image);
        let da = (ours.p - want).length();
        assert!(
            da < 1e-9,
            "aimed ray Hy={} Px={} Py={}: {da:e} mm off",
            r["Hy"],
            r["Px"],
            r["Py"]
        );
    }
    eprintln!(
        "worst intercept error {:e} mm, worst OPL error {:e} mm",
        worst.0, worst.1
    );
}
