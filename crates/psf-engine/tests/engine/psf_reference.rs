//! PSFs of the Cooke triplet: our FFT and Huygens PSFs against each other and the
//! reference tool's Strehl ratios.

use crate::common;
use psf_engine::psf::{psf, Method, PsfOptions};

fn rel_l2(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

fn opts(method: Method, n: usize) -> PsfOptions {
    PsfOptions {
        method,
        pixel_mm: 0.25e-3,
        size: 128,
        pupil_samples: n,
        ..Default::default()
    }
}

#[test]
fn fft_matches_huygens_on_axis_and_at_the_field_edge() {
    let lens = common::cooke();
    for field in [0.0, 14.0, 20.0] {
        let f = psf(&lens, field, 550.0, &opts(Method::Fft, 128)).unwrap();
        let h = psf(&lens, field, 550.0, &opts(Method::Huygens, 128)).unwrap();
        let e = rel_l2(&f.data, &h.data);
        eprintln!(
            "field {field}: rel L2 {e:.4}, strehl fft {:?} huygens {:?}; fft {:?}",
            f.strehl,
            h.strehl,
            f.diagnostics.to_json()
        );
        assert!(e < 0.03, "field {field}: FFT vs Huygens relative L2 {e}");
    }
}

/// The reference Strehl ratios are sampled peaks; at 14 and 20 degrees the reference FFT
/// samples the peak at 1.4-1.5 um (and with one averaged f-number at 20 deg), and its Huygens
/// figure is normalized by the on-axis peak, so those two fields are compared in the
/// closing notes rather than here. Fields 0-10 deg hold to 2% against the reference FFT.
#[test]
fn strehl_matches_reference_within_2_percent() {
    let r = common::read_json("cooke_triplet_reference.json");
    let lens = common::cooke();
    for pf in r["per_field"].as_array().unwrap() {
        let field = pf["field_deg"].as_f64().unwrap();
        if field > 10.0 {
            continue;
        }
        let want = pf["strehl_0p55_fft_pupil128_grid256"].as_f64().unwrap();
        for m in [Method::Fft, Method::Huygens] {
            let got = psf(&lens, field, 550.0, &opts(m, 128))
                .unwrap()
                .strehl
                .expect("a Strehl ratio");
            eprintln!(
                "field {field} {m:?}: strehl {got:.5} vs reference {want:.5} ({:+.2}%)",
                100.0 * (got / want - 1.0)
            );
            assert!((got / want - 1.0).abs() < 0.02, "field {field} {m:?}: {got} vs {want}");
        }
    }
}
