//! The wavefront (OPD) of `wavefront::field_wavefront` against closed forms: a lens free of
//! aberration on axis has none; a defocus dz has W20 = n' dz / (8 N^2) and, piston
//! removed, RMS W20 / (2 sqrt 3) (Born & Wolf 9.4); and against the FFT PSF's pupil.
use crate::common;

use psf_engine::psf::pupil::sample_pupil;
use psf_engine::wavefront::{field_wavefront, Tilt};
use psf_engine::{Aiming, Lens, System};
use serde_json::json;

/// Gauss-Legendre in rho^2 x equally spaced azimuths over the whole unit pupil; weights
/// sum to 1.
fn quadrature(rings: usize, arms: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    // Gauss-Legendre nodes on [-1, 1] by Newton on P_n.
    let mut nodes = vec![];
    for i in 0..rings {
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (rings as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=rings {
                let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            dp = rings as f64 * (x * p1 - p0) / (x * x - 1.0);
            let dx = p1 / dp;
            x -= dx;
            if dx.abs() < 1e-15 {
                break;
            }
        }
        nodes.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
    }
    let (mut px, mut py, mut w) = (vec![], vec![], vec![]);
    for (x, wx) in nodes {
        let r = (0.5 * (1.0 + x)).sqrt();
        for a in 0..arms {
            let t = 2.0 * std::f64::consts::PI * (a as f64 + 0.5) / arms as f64;
            px.push(r * t.cos());
            py.push(r * t.sin());
            w.push(0.5 * wx / arms as f64);
        }
    }
    (px, py, w)
}

/// Plano-convex singlet, plane side first (the stop), rear surface the hyperboloid
/// k = -n^2 that focuses an axial plane wave without aberration at f = -R / (n - 1).
fn hyperbolic(f: f64, epd: f64, dz: f64) -> Lens {
    let n: f64 = 1.5;
    Lens::from_json(
        &json!({
            "aperture": {"type": "epd", "value": epd}, "wavelengths_nm": [550.0], "fields_deg": [0.0],
            "surfaces": [
                {"radius": "inf", "thickness": 5.0, "material": {"n": n}, "stop": true},
                {"radius": -(n - 1.0) * f, "conic": -n * n, "thickness": f + dz, "material": "air"}
            ]
        })
        .to_string(),
    )
    .unwrap()
}

#[test]
fn perfect_lens_has_no_wavefront_error() {
    let lens = hyperbolic(100.0, 20.0, 0.0);
    let (px, py, w) = quadrature(8, 16);
    for tilt in [Tilt::PerWavelength, Tilt::Shared] {
        let wf = field_wavefront(&lens, 0.0, &[550.0], &[1.0], &px, &py, &w, Aiming::Paraxial, tilt).unwrap();
        assert!(wf.status.iter().all(|&s| s == 0));
        assert!(wf.rms_waves[0] < 1e-7, "perfect lens RMS {} waves", wf.rms_waves[0]);
        assert!(wf.opd_waves.iter().all(|o| o.abs() < 1e-6));
    }
    // the same lens 0.5 mm out of focus is not perfect (the test can fail)
    let wf = field_wavefront(
        &hyperbolic(100.0, 20.0, 0.5),
        0.0,
        &[550.0],
        &[1.0],
        &px,
        &py,
        &w,
        Aiming::Paraxial,
        Tilt::PerWavelength,
    )
    .unwrap();
    assert!(wf.rms_waves[0] > 0.5);
}

#[test]
fn defocus_matches_w20_closed_form() {
    // f/20, near the paraxial limit: the rim ray's real angle (its surface point lies a sag
    // of 0.06 mm further from the image) makes sin^2 u' 0.2 % smaller than (1 / 2N)^2, and
    // the second order in dz adds ~ dz / f
    let (f, epd) = (100.0, 5.0);
    let n_f = f / epd;
    let (px, py, w) = quadrature(8, 16);
    let lambda = 550e-6;
    for dz in [-0.2, 0.1, 0.2] {
        let wf = field_wavefront(
            &hyperbolic(f, epd, dz),
            0.0,
            &[550.0],
            &[1.0],
            &px,
            &py,
            &w,
            Aiming::Paraxial,
            Tilt::PerWavelength,
        )
        .unwrap();
        let w20 = dz / (8.0 * n_f * n_f) / lambda; // waves
        let rms = w20.abs() / (2.0 * 3f64.sqrt());
        let rel = (wf.rms_waves[0] - rms).abs() / rms;
        assert!(
            rel < 5e-3,
            "dz {dz}: RMS {} waves, closed form {rms} ({rel:.2e})",
            wf.rms_waves[0]
        );
        // the per-ray OPD is W20 (rho^2 - 1/2), piston removed; sign: a ray at the rim
        // travels further to the reference sphere when the image lies beyond the focus
        for k in 0..px.len() {
            let rho2 = px[k] * px[k] + py[k] * py[k];
            let want = -w20 * (rho2 - 0.5);
            assert!(
                (wf.opd_waves[k] - want).abs() < 2e-2 * w20.abs(),
                "dz {dz}, ray {k}: {} vs {want}",
                wf.opd_waves[k]
            );
        }
        // no tilt on axis
        assert!(wf.tilt_mm[0][0].abs() < 1e-12 && wf.tilt_mm[0][1].abs() < 1e-12);
    }
}

#[test]
fn rms_matches_the_fft_pupils_wavefront() {
    // An independent sampling of the same OPD: the FFT PSF's square pupil grid, flux
    // weighted, piston and tilt removed by its own fit.
    let lens = common::cooke();
    let (px, py, w) = quadrature(12, 24);
    for field in [0.0, 14.0, 20.0] {
        let wf = field_wavefront(
            &lens,
            field,
            &[550.0],
            &[1.0],
            &px,
            &py,
            &w,
            Aiming::Paraxial,
            Tilt::PerWavelength,
        )
        .unwrap();
        let sys = System::new(&lens, 550.0).unwrap();
        let p = sample_pupil(&sys, field, Aiming::Paraxial, 512).unwrap();
        let fft = p.rms_wavefront();
        let rel = (wf.rms_waves[0] - fft).abs() / fft;
        assert!(
            rel < 1e-2,
            "field {field}: quadrature {} vs FFT pupil {fft} waves ({rel:.2e})",
            wf.rms_waves[0]
        );
    }
}

#[test]
fn shared_tilt_keeps_lateral_colour() {
    // Off axis the three wavelengths' images stand apart (lateral colour): one tilt for
    // all leaves that in the OPD, one per wavelength removes it.
    let lens = common::paper_triplet();
    let (px, py, w) = quadrature(6, 12);
    let wl = [470.0, 550.0, 650.0];
    let per = field_wavefront(
        &lens,
        14.86,
        &wl,
        &[1.0; 3],
        &px,
        &py,
        &w,
        Aiming::Paraxial,
        Tilt::PerWavelength,
    )
    .unwrap();
    let shared = field_wavefront(
        &lens,
        14.86,
        &wl,
        &[1.0; 3],
        &px,
        &py,
        &w,
        Aiming::Paraxial,
        Tilt::Shared,
    )
    .unwrap();
    let ms = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    assert!(ms(&shared.rms_waves) > ms(&per.rms_waves));
    // per-wavelength tilts differ along y (the field direction), the shared ones do not
    assert!((per.tilt_mm[0][1] - per.tilt_mm[2][1]).abs() > 1e-4);
    assert_eq!(shared.tilt_mm[0], shared.tilt_mm[2]);
    // on axis the two agree (no lateral colour by symmetry)
    let a = field_wavefront(
        &lens,
        0.0,
        &wl,
        &[1.0; 3],
        &px,
        &py,
        &w,
        Aiming::Paraxial,
        Tilt::PerWavelength,
    )
    .unwrap();
    let b = field_wavefront(&lens, 0.0, &wl, &[1.0; 3], &px, &py, &w, Aiming::Paraxial, Tilt::Shared).unwrap();
    for (x, y) in a.rms_waves.iter().zip(&b.rms_waves) {
        assert!((x - y).abs() < 1e-9 * x.max(1e-9));
    }
}

#[test]
fn bad_weights_are_refused() {
    let lens = hyperbolic(100.0, 10.0, 0.0);
    let e = field_wavefront(
        &lens,
        0.0,
        &[550.0],
        &[1.0],
        &[0.0],
        &[0.0],
        &[f64::NAN],
        Aiming::Paraxial,
        Tilt::Shared,
    );
    assert!(e.is_err());
    let e = field_wavefront(
        &lens,
        0.0,
        &[550.0],
        &[],
        &[0.0],
        &[0.0],
        &[1.0],
        Aiming::Paraxial,
        Tilt::Shared,
    );
    assert!(e.is_err());
}

#[test]
fn image_space_telecentric_lens_is_refused() {
    // the stop at the front focal point: the paraxial exit pupil lies ~1e12 mm away, where
    // the reference sphere's sag is below f64's rounding of R^2
    let singlet = |gap: f64| {
        Lens::from_json(
            &json!({
                "aperture": {"type": "epd", "value": 4.0}, "wavelengths_nm": [550.0], "fields_deg": [0.0],
                "surfaces": [
                    {"radius": "inf", "thickness": gap, "material": "air", "stop": true},
                    {"radius": 50.0, "thickness": 1.0, "material": {"n": 1.5}},
                    {"radius": -50.0, "thickness": 50.0, "material": "air"}
                ]
            })
            .to_string(),
        )
        .unwrap()
    };
    let ffl = psf_engine::paraxial(&singlet(1e-9), 550.0).unwrap().ffl;
    let lens = singlet(-ffl);
    let (px, py, w) = quadrature(4, 8);
    let e = field_wavefront(
        &lens,
        0.0,
        &[550.0],
        &[1.0],
        &px,
        &py,
        &w,
        Aiming::Paraxial,
        Tilt::PerWavelength,
    );
    assert!(
        matches!(&e, Err(err) if err.to_string().contains("telecentric")),
        "{:?}",
        e.err()
    );
    // a stop 10 mm off the focal point is fine
    assert!(field_wavefront(
        &singlet(-ffl - 10.0),
        0.0,
        &[550.0],
        &[1.0],
        &px,
        &py,
        &w,
        Aiming::Paraxial,
        Tilt::PerWavelength
    )
    .is_ok());
}
