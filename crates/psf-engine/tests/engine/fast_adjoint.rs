//! The fast FFT PSF's reverse pass (`psf::fast_adjoint::linearize`, then `vjp`): the gradient of
//! L = sum(g * PSF) along the lens parameters against central differences of the engine's own
//! PSF of the perturbed lens (`tangent::perturbed`), J^T g for a random g and for g = the PSF
//! itself (L its sum of squares: sharpness), at three fields and two wavelengths, on the
//! aspheric paper triplet, the spherical Cooke triplet and the eight-element double Gauss.
use crate::common;
use psf_engine::psf::fast::fast_psf;
use psf_engine::psf::fast_adjoint::linearize;
use psf_engine::psf::{Diagnostics, Method, PsfOptions};
use psf_engine::tangent::{perturbed, Param};
use psf_engine::{Lens, System};

fn opts() -> PsfOptions {
    PsfOptions {
        method: Method::Fft,
        pixel_mm: 1e-3,
        size: 64,
        pupil_samples: 64,
        fast: true,
        ..Default::default()
    }
}

/// A fixed pseudo-random g in [-1, 1] (a 64-bit LCG: the same every run).
fn random_g(n: usize, seed: u64) -> Vec<f64> {
    let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        })
        .collect()
}

/// The fast PSF and the choices that must hold between the sides of a difference.
fn psf_of(lens: &Lens, wl: f64, field: f64, o: &PsfOptions) -> (Vec<f64>, String) {
    let sys = System::new(lens, wl).unwrap();
    let mut d = Diagnostics::default();
    let p = fast_psf(&sys, field, o, &mut d)
        .unwrap()
        .expect("the fast path applies");
    let v = &d.values;
    let choice = format!("{} {} {}", v["pupil_fit_degree"], v["fft_grid"], v["pupil_eval"]);
    (p, choice)
}

/// max over the cases of |vjp - differences| / |differences| (vector norms over the
/// parameters), asserting the discrete choices equal on both sides of every difference.
fn worst<const N: usize>(lens: &Lens, params: &[Param; N], steps: &[f64; N], wls: &[f64]) -> f64 {
    let o = opts();
    let mut worst = 0.0f64;
    for &wl in wls {
        for field in [0.0, 0.7 * lens.max_field_deg(), lens.max_field_deg()] {
            let sys = System::new(lens, wl).unwrap();
            let (p0, choice0) = psf_of(lens, wl, field, &o);
            for g in [random_g(p0.len(), (field * 10.0) as u64 + wl as u64), p0.clone()] {
                let mut d = Diagnostics::default();
                let lin = linearize::<N>(&sys, field, &o, params, &mut d).unwrap().unwrap();
                assert_eq!(lin.psf, p0, "the linearized PSF is the forward one");
                let grad = lin.vjp(&g).unwrap();
                let loss = |l: &Lens| -> (f64, String) {
                    let (p, c) = psf_of(l, wl, field, &o);
                    (p.iter().zip(&g).map(|(a, b)| a * b).sum(), c)
                };
                let (mut num, mut den) = (0.0, 0.0);
                for (k, (&par, &h)) in params.iter().zip(steps).enumerate() {
                    // Richardson's extrapolation of central differences at h and h / 2
                    // (truncation ~ h^4: the steps can be large enough that the float32
                    // field's round-off stays small)
                    let cd = |h: f64| {
                        let (a, ca) = loss(&perturbed(lens, par, h).unwrap());
                        let (b, cb) = loss(&perturbed(lens, par, -h).unwrap());
                        assert!(ca == choice0 && cb == choice0, "{par:?}: {ca} / {cb} vs {choice0}");
                        (a - b) / (2.0 * h)
                    };
                    let fd = (4.0 * cd(0.5 * h) - cd(h)) / 3.0;
                    num += (grad[k] - fd).powi(2);
                    den += fd * fd;
                }
                let rel = (num / den).sqrt();
                assert!(den > 0.0, "no parameter moves the PSF");
                worst = worst.max(rel);
            }
        }
    }
    worst
}

#[test]
fn the_reverse_pass_of_the_aspheric_triplets_fast_psf_matches_central_differences() {
    // traced as the dataset traces it (no clear apertures: the design's own beam)
    let lens = common::paper_triplet_unclipped();
    let last = lens.surfaces.len() - 1;
    let params = [
        Param::Curvature(0),
        Param::Conic(0),
        Param::Aspheric(0, 1),
        Param::Curvature(1),
        Param::Thickness(1),
        Param::Curvature(2),
        Param::Thickness(3),
        Param::Curvature(5),
        Param::Aspheric(5, 2),
        Param::Curvature(6),
        Param::Thickness(last),
        Param::FNumber,
    ];
    let steps = [4e-6, 1e-3, 1e-8, 4e-6, 1e-4, 4e-6, 1e-3, 4e-6, 1e-9, 4e-6, 1e-4, 1e-3];
    let err = worst::<12>(&lens, &params, &steps, &[550.0, 460.0]);
    eprintln!("paper triplet: relative error of J^T g {err:.2e}");
    assert!(err < 5e-3, "relative error of J^T g: {err:e}");
}

#[test]
fn the_reverse_pass_of_the_cooke_triplets_fast_psf_matches_central_differences() {
    let lens = common::cooke();
    let last = lens.surfaces.len() - 1;
    let params = [
        Param::Curvature(0),
        Param::Curvature(1),
        Param::Thickness(1),
        Param::Curvature(3),
        Param::Thickness(2),
        Param::Thickness(last),
        Param::Epd,
    ];
    let steps = [4e-6, 4e-6, 1e-4, 4e-6, 1e-4, 1e-4, 1e-3];
    let err = worst::<7>(&lens, &params, &steps, &[587.6]);
    eprintln!("Cooke triplet: relative error of J^T g {err:.2e}");
    assert!(err < 5e-3, "relative error of J^T g: {err:e}");
}

#[test]
fn the_reverse_pass_of_the_eight_element_lenss_fast_psf_matches_central_differences() {
    // the apochromatic double Gauss (JP 2025-108279 A), unclipped: 15 surfaces, all spherical
    let lens = common::fixture_lens("apo_gauss_8e");
    let last = lens.surfaces.len() - 1;
    let params = [
        Param::Radius(0),
        Param::Radius(4),
        Param::Radius(9),
        Param::Radius(14),
        Param::Thickness(6),
        Param::Thickness(12),
        Param::Thickness(last),
        Param::FNumber,
    ];
    let r = |i: usize| 1.0 / lens.surfaces[i].curvature;
    let steps = [
        2e-5 * r(0).abs(),
        2e-5 * r(4).abs(),
        2e-5 * r(9).abs(),
        2e-5 * r(14).abs(),
        1e-3,
        1e-3,
        1e-4,
        1e-3,
    ];
    let err = worst::<8>(&lens, &params, &steps, &[587.6]);
    eprintln!("eight-element lens: relative error of J^T g {err:.2e}");
    assert!(err < 5e-3, "relative error of J^T g: {err:e}");
}
