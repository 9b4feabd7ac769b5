//! Relative illumination (spot.rs): the quadrature, and the cos^4 law of a thin lens at and
//! off its paraxial focus (the Python suite adds brute-force ray counts and optiland's rays).

use crate::common;
use psf_engine::aim::Aiming;
use psf_engine::spot::{gauss_pupil, irradiance, relative_illumination_from, PupilGrid};

#[test]
fn gauss_pupil_integrates_the_unit_disc_and_its_polynomials() {
    let (x, y, w) = gauss_pupil();
    assert_eq!(x.len(), 24);
    assert!(x.iter().all(|&v| v > 0.0));
    let area: f64 = w.iter().sum();
    assert!((area - std::f64::consts::PI).abs() < 1e-12, "{area}");
    // integrals over the disc of r^2 (pi / 2), r^4 (pi / 3), y^2 (pi / 4), x^2 y^2 (pi / 24)
    let m = |f: &dyn Fn(f64, f64) -> f64| x.iter().zip(&y).zip(&w).map(|((&a, &b), &c)| c * f(a, b)).sum::<f64>();
    let pi = std::f64::consts::PI;
    for (got, want) in [
        (m(&|a, b| a * a + b * b), pi / 2.0),
        (m(&|a, b| (a * a + b * b).powi(2)), pi / 3.0),
        (m(&|_, b| b * b), pi / 4.0),
        (m(&|a, b| a * a * b * b), pi / 24.0),
    ] {
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }
}

#[test]
fn clear_grid_agrees_with_a_fine_midpoint_grid() {
    let lens = common::cooke();
    for f in [0.0, 10.0, 20.0] {
        let (a, clear) = irradiance(&lens, f, 550.0, PupilGrid::Clear, Aiming::Paraxial).unwrap();
        let (b, _) = irradiance(&lens, f, 550.0, PupilGrid::Rings(64), Aiming::Paraxial).unwrap();
        assert!(clear);
        assert!((a / b - 1.0).abs() < 2e-6, "{f} deg: {a} vs {b}");
    }
}

#[test]
fn thin_lens_follows_cos4_at_and_off_focus() {
    // f = 50 mm plano-convex (n 1.5, R 25 mm), 1 mm EPD, stop on the lens; BFL = f - t/n
    for dz in [0.0, 1.0, -1.0] {
        let lens = common::singlet(25.0, 1e18, 0.02, 1.5, 1.0, 50.0 - 0.02 / 1.5 + dz);
        for f in [10.0f64, 20.0, 30.0] {
            let ri = relative_illumination_from(&lens, f, 550.0, Aiming::Paraxial, None).unwrap();
            let c4 = f.to_radians().cos().powi(4);
            assert!((ri / c4 - 1.0).abs() < 1e-3, "dz {dz}, {f} deg: {ri} vs cos^4 {c4}");
        }
    }
}

#[test]
fn a_field_that_folds_is_found_and_its_rgb_psfs_refused() {
    use psf_engine::rgb::psf_rgb;
    use psf_engine::spot::field_fold;
    // the Cooke triplet and a sampled design brighter at the corner than on the axis (1.23,
    // a flux count agrees: tests/lens/test_relative_illumination.py) do not fold
    assert_eq!(
        field_fold(&common::cooke(), 20.0, 550.0, Aiming::Paraxial).unwrap(),
        None
    );
    let bright = common::fixture_lens("detect_wide_bright_corner");
    assert_eq!(field_fold(&bright, 14.9, 550.0, Aiming::Paraxial).unwrap(), None);
    // a sampled design whose rim rays' image height falls near its 14.9 deg field
    let folds = common::fixture_lens("detect_wide_folds");
    let f = field_fold(&folds, 14.9, 550.0, Aiming::Paraxial)
        .unwrap()
        .expect("a fold");
    assert!(f.step_mm < 0.0 && (f.field_deg - 14.9).abs() < 1e-9, "{f:?}");
    // its RGB PSFs are refused at every field (light from the fold lands everywhere), the
    // bright design's computed with its relative illumination above 1
    let channels = vec![vec![(650.0, 1.0)], vec![(550.0, 1.0)], vec![(470.0, 1.0)]];
    let o = psf_engine::psf::PsfOptions {
        size: 16,
        ..Default::default()
    };
    let err = psf_rgb(&folds, 5.0, &channels, &o).err().expect("refused").to_string();
    assert!(err.contains("the image of the field folds"), "{err}");
    let ri = psf_rgb(&bright, 14.9, &channels, &o).unwrap().relative_illumination;
    assert!(ri.iter().all(|&v| v > 1.05 && v.is_finite()), "{ri:?}");
    // the batch checks each design once over its own fields (a field beyond them anew) and
    // refuses or computes exactly as field by field
    let fields = [0.0, 5.0, 14.9, 16.0];
    let b = psf_engine::rgb::psf_batch(&[bright.clone(), folds.clone()], &fields, &channels, &o).unwrap();
    let refused = b.errors[1].as_deref().expect("the folding design refused");
    assert!(
        refused.starts_with("field 0 deg: ") && refused.contains("the image of the field folds"),
        "{refused}"
    );
    let beyond = psf_rgb(&bright, 16.0, &channels, &o).err().map(|e| e.to_string());
    assert_eq!(
        b.errors[0].as_ref().map(|e| e.starts_with("field 16 deg: ")),
        beyond.as_ref().map(|_| true)
    );
    for (i, &f) in fields.iter().enumerate().filter(|_| beyond.is_none()) {
        let one = psf_rgb(&bright, f, &channels, &o).unwrap();
        assert_eq!(
            &b.relative_illumination[i * 3..i * 3 + 3],
            &one.relative_illumination[..],
            "{f} deg"
        );
        let psf: Vec<f32> = one.data.iter().map(|&v| v as f32).collect();
        assert_eq!(&b.psf[i * 3 * 256..(i + 1) * 3 * 256], &psf[..], "{f} deg");
    }
}
