//! The fast FFT's traced pupil (psf/traced.rs) on a design whose pupil no polynomial follows
//! (tests/data/lenses/detect_wide_traced.json: a 170 um RMS spot at 14.9 deg), against
//! Huygens, the independent method (a sum over the same pupil's wavelets, no FFT, no direction
//! grid); and on a design whose pupil's map to the directions folds, where it must fall back.
//!
//! Tolerance (asserted): relative L1 <= 1 % against Huygens at 1024 pupil samples over a
//! 64 x 64 um window (measured 0.2 %; Huygens at 512 and 1024 differ by ~0.3 % there).

use crate::common;
use psf_engine::psf::{psf, Method, PsfOptions};

fn rel_l1(a: &[f64], b: &[f64]) -> f64 {
    let (sa, sb): (f64, f64) = (a.iter().sum(), b.iter().sum());
    a.iter().zip(b).map(|(x, y)| (x / sa - y / sb).abs()).sum()
}

fn fast() -> PsfOptions {
    PsfOptions {
        method: Method::Fft,
        fast: true,
        size: 64,
        pixel_mm: 1e-3,
        pupil_samples: 64,
        ..Default::default()
    }
}

#[test]
fn traced_pupil_matches_huygens_on_a_large_aberrated_spot() {
    let lens = common::fixture_lens("detect_wide_traced");
    let p = psf(&lens, 14.9, 550.0, &fast()).unwrap();
    let d = &p.diagnostics;
    assert_eq!(
        d.values["fft_mode"],
        "direction_grid",
        "{:?}",
        d.values.get("fast_fallback")
    );
    assert_eq!(d.values["pupil_eval"], "traced");
    assert!(d.values["pupil_area_error"].as_f64().unwrap().abs() <= 1e-3);
    assert!(
        !d.warnings
            .iter()
            .any(|w| w.contains("wraps") || w.contains("undersampled")),
        "{:?}",
        d.warnings
    );
    let h = psf(
        &lens,
        14.9,
        550.0,
        &PsfOptions {
            method: Method::Huygens,
            fast: false,
            pupil_samples: 1024,
            ..fast()
        },
    )
    .unwrap();
    let e = rel_l1(&p.data, &h.data);
    let (sp, sh): (f64, f64) = (p.data.iter().sum(), h.data.iter().sum());
    println!("traced vs Huygens N=1024: rel L1 {e:.4}, window energy {sp:.5} / {sh:.5}");
    assert!(e <= 0.01, "traced pupil vs Huygens: rel L1 {e:.4}");
    assert!((sp - sh).abs() <= 0.01 * sh, "window energy {sp} vs {sh}");
}

#[test]
fn a_pupil_whose_direction_map_folds_falls_back_instead_of_losing_light() {
    let lens = common::fixture_lens("detect_wide_pupil_fold");
    // The general FFT that takes over refuses this window (its Taylor series does not
    // converge): an error naming the PSF, or a general-mode PSF; never a traced one.
    match psf(&lens, 13.658333333333333, 550.0, &PsfOptions { size: 16, ..fast() }) {
        Ok(p) => {
            assert_eq!(p.diagnostics.values["fft_mode"], "general");
            let why = p.diagnostics.values["fast_fallback"].as_str().unwrap().to_string();
            assert!(why.contains("traced pupil"), "{why}");
        }
        Err(e) => assert!(e.to_string().contains("PSF"), "{e}"),
    }
}

/// auto's largest fast candidate (1024 cells across the pupil) is budgeted as what it
/// allocates, not as a general FFT on a 4096-point grid (2 GiB): below the size at which the
/// engine reads the memory available, so a loaded machine never refuses it. The general FFT
/// at 1024 samples still is budgeted at its size.
#[test]
fn the_fast_paths_memory_need_is_its_own() {
    let fast = PsfOptions {
        pupil_samples: 1024,
        size: 246,
        ..fast()
    };
    assert!(
        fast.memory().total() <= 256.0 * 1024.0 * 1024.0,
        "{}",
        fast.memory().total()
    );
    let general = PsfOptions { fast: false, ..fast };
    assert!(general.memory().total() >= 512.0 * 1024.0 * 1024.0);
}
