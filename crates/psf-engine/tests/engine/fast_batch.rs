//! The batch RGB PSF path of the dataset generator (fast FFT on a direction-cosine grid,
//! psf/fast.rs) against the general FFT with a dense pupil, on the bundled paper-triplet
//! and perturbed copies; its relative illumination against the general path's (one
//! computation, spot.rs, whatever the PSF path: the two must agree); its
//! independence of the thread count; its failures and warnings.
//!
//! Tolerances (asserted): relative L1 of every PSF (each normalized to unit sum) <= 1%
//! against the general FFT with 256 pupil samples (itself within ~0.2% of 512 samples);
//! relative illumination within 1e-3 (seen: 0, the same computation).

use crate::common;
use psf_engine::psf::{psf, Method, PsfOptions};
use psf_engine::rgb::{psf_batch, Channels};
use psf_engine::Lens;
use serde_json::Value;

const L1_TOL: f64 = 0.01;
const RI_TOL: f64 = 1e-3;

fn fields() -> Vec<f64> {
    (0..13).map(|i| 14.9 * i as f64 / 12.0).collect()
}

fn rgb() -> Channels {
    vec![vec![(650.0, 1.0)], vec![(550.0, 1.0)], vec![(470.0, 1.0)]]
}

/// The dataset's settings: 128 x 128 at 1 um, point sampling, fast path.
fn dataset_opts() -> PsfOptions {
    PsfOptions {
        method: Method::Fft,
        pixel_mm: 1e-3,
        size: 128,
        pupil_samples: 64,
        fast: true,
        ..Default::default()
    }
}

fn reference_opts(n: usize) -> PsfOptions {
    PsfOptions {
        pupil_samples: n,
        fast: false,
        ..dataset_opts()
    }
}

fn normalized(v: &[f64]) -> Vec<f64> {
    let s: f64 = v.iter().sum();
    v.iter().map(|x| x / s).collect()
}

fn rel_l1(a: &[f64], b: &[f64]) -> f64 {
    let (a, b) = (normalized(a), normalized(b));
    a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum()
}

/// Batch (fast) vs the 256-sample general FFT for every field and channel of `lens`;
/// relative illumination vs the general path's. Returns the worst L1.
fn check_design(label: &str, lens: &Lens, fields: &[f64]) -> f64 {
    let o = dataset_opts();
    let ch = rgb();
    let b = psf_batch(std::slice::from_ref(lens), fields, &ch, &o).unwrap();
    assert!(b.errors[0].is_none(), "{label}: {:?}", b.errors[0]);
    let slow = psf_batch(
        std::slice::from_ref(lens),
        fields,
        &ch,
        &PsfOptions {
            fast: false,
            ..o.clone()
        },
    )
    .unwrap();
    let s2 = o.size * o.size;
    let mut worst: f64 = 0.0;
    for (fi, &f) in fields.iter().enumerate() {
        for (c, list) in ch.iter().enumerate() {
            let wl = list[0].0;
            let fast = psf(lens, f, wl, &o).unwrap();
            assert_eq!(
                fast.diagnostics.values["fft_mode"],
                "direction_grid",
                "{label} {f} deg {wl} nm: {:?}",
                fast.diagnostics.values.get("fast_fallback")
            );
            let k = (fi * ch.len() + c) * s2;
            let batch: Vec<f64> = b.psf[k..k + s2].iter().map(|&v| v as f64).collect();
            // The batch holds this very PSF, normalized, in f32.
            let nf = normalized(&fast.data);
            assert!(
                batch
                    .iter()
                    .zip(&nf)
                    .all(|(x, y)| (x - y).abs() <= 1e-7 * y.abs().max(1e-30) + 1e-12),
                "{label} {f} deg {wl} nm: batch differs from psf()"
            );
            let reference = psf(lens, f, wl, &reference_opts(256)).unwrap();
            let e = rel_l1(&fast.data, &reference.data);
            let (ri, ri_ref) = (
                b.relative_illumination[fi * ch.len() + c],
                slow.relative_illumination[fi * ch.len() + c],
            );
            println!(
                "{label} {f:6.3} deg {wl} nm: rel L1 {e:.4}, RI {ri:.6} vs {ri_ref:.6} ({:.1e}), spot {:.0} um, grid {}, fit degree {}, residual {:.1e} waves",
                (ri - ri_ref).abs(),
                fast.diagnostics.values["spot_extent_y_um"].as_f64().unwrap().max(fast.diagnostics.values["spot_extent_x_um"].as_f64().unwrap()),
                fast.diagnostics.values["fft_grid"],
                fast.diagnostics.values["pupil_fit_degree"],
                fast.diagnostics.values["pupil_fit_residual_waves"].as_f64().unwrap()
            );
            assert!(e <= L1_TOL, "{label} {f} deg {wl} nm: relative L1 {e:.4} > {L1_TOL}");
            assert!(
                (ri - ri_ref).abs() <= RI_TOL,
                "{label} {f} deg {wl} nm: relative illumination {ri} vs {ri_ref}"
            );
            worst = worst.max(e);
        }
    }
    assert!(b.psf.iter().all(|v| v.is_finite()) && b.relative_illumination.iter().all(|v| v.is_finite()));
    worst
}

#[test]
fn paper_triplet_matches_the_dense_general_fft_at_all_fields_and_wavelengths() {
    let worst = check_design("paper-triplet", &common::paper_triplet(), &fields());
    println!("paper-triplet: worst relative L1 {worst:.4} (tolerance {L1_TOL})");
}

/// Perturbed copies: radii, thicknesses, conics and aspheric terms moved by a few percent
/// (a deterministic pattern per design), as the dataset's random designs near the nominal,
/// traced as the generator traces them by default (apertures "auto": no clear apertures;
/// the f-number sets the beam).
fn perturbed(seed: u64) -> Lens {
    let mut v = common::paper_triplet_json();
    for s in v["surfaces"].as_array_mut().unwrap() {
        s.as_object_mut().unwrap().remove("semi_diameter");
    }
    let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let mut rnd = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    for s in v["surfaces"].as_array_mut().unwrap() {
        if let Some(r) = s["radius"].as_f64() {
            s["radius"] = Value::from(r * (1.0 + 0.02 * rnd()));
        }
        let t = s["thickness"].as_f64().unwrap();
        s["thickness"] = Value::from(t + 0.05 * rnd());
        if let Some(k) = s.get("conic").and_then(Value::as_f64) {
            s["conic"] = Value::from(k + 0.05 * rnd());
        }
        if let Some(a) = s.get_mut("aspheric").and_then(Value::as_object_mut) {
            for (_, c) in a.iter_mut() {
                *c = Value::from(c.as_f64().unwrap() * (1.0 + 0.05 * rnd()));
            }
        }
    }
    Lens::from_json(&v.to_string()).unwrap()
}

#[test]
fn perturbed_designs_match_the_dense_general_fft() {
    let fields = [0.0, 7.45, 12.4, 14.9];
    let mut worst: f64 = 0.0;
    for seed in 1..=3 {
        worst = worst.max(check_design(&format!("perturbed #{seed}"), &perturbed(seed), &fields));
    }
    // Out of focus (image plane 0.15 / 0.4 mm back): spots of ~50-100 um, FFT grids of
    // 256-512 chosen from the spot.
    for (k, dz) in [0.15, 0.4].into_iter().enumerate() {
        let mut v = common::paper_triplet_json();
        let last = v["surfaces"].as_array().unwrap().len() - 1;
        let t = v["surfaces"][last]["thickness"].as_f64().unwrap();
        v["surfaces"][last]["thickness"] = Value::from(t + dz);
        worst = worst.max(check_design(
            &format!("defocused #{k}"),
            &Lens::from_json(&v.to_string()).unwrap(),
            &fields,
        ));
    }
    println!("perturbed designs: worst relative L1 {worst:.4} (tolerance {L1_TOL})");
}

/// Bit-identical output with 1 and 2 threads (the generator promises byte-identical
/// arrays for a seed whatever the thread count), a failing design among them included.
#[test]
fn batch_output_does_not_depend_on_the_thread_count() {
    let mut bad = common::paper_triplet_json();
    // PMMA defined only from 550 nm (beyond the 10% of its span that the engine
    // extrapolates): the 470 nm channel fails for this design alone.
    bad["surfaces"][0]["material"]["range_um"] = serde_json::json!([0.55, 1.052]);
    let lenses = vec![
        common::paper_triplet(),
        Lens::from_json(&bad.to_string()).unwrap(),
        perturbed(7),
    ];
    let fields = [0.0, 5.0, 14.9];
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| psf_batch(&lenses, &fields, &rgb(), &dataset_opts()).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert!(
        a.psf.iter().zip(&b.psf).all(|(x, y)| x.to_bits() == y.to_bits()),
        "PSFs differ between 1 and 2 threads"
    );
    assert!(a
        .relative_illumination
        .iter()
        .zip(&b.relative_illumination)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!(a.errors, b.errors);
    // The failing design keeps its error string and zeros; the others are whole.
    assert!(a.errors[0].is_none() && a.errors[2].is_none());
    let e = a.errors[1].as_deref().unwrap();
    assert!(e.contains("470") || e.contains("0.47"), "{e}");
    let per = fields.len() * 3 * 128 * 128;
    assert!(a.psf[per..2 * per].iter().all(|&v| v == 0.0));
    assert!(a.psf.iter().all(|v| v.is_finite()));
    for (i, chunk) in a.psf.chunks_exact(128 * 128).enumerate() {
        if i / (fields.len() * 3) != 1 {
            let s: f64 = chunk.iter().map(|&v| v as f64).sum();
            assert!((s - 1.0).abs() < 1e-4, "channel {i} sums to {s}");
        }
    }
}

/// The general FFT's sampling checks hold on the fast path: energy outside a small window
/// is reported, diagnostics name the path, the grid and the fit; where the fast path does
/// not apply (vignetting, real aiming, integrated pixels) the general FFT runs and says why.
#[test]
fn fast_path_keeps_the_sampling_checks_and_falls_back_where_it_does_not_apply() {
    let lens = common::paper_triplet();
    let small = PsfOptions {
        size: 16,
        ..dataset_opts()
    };
    let p = psf(&lens, 14.9, 550.0, &small).unwrap();
    let d = &p.diagnostics;
    assert_eq!(d.values["fft_mode"], "direction_grid");
    assert!(
        d.warnings.iter().any(|w| w.contains("falls outside the 16x16 window")),
        "{:?}",
        d.warnings
    );
    assert!(d.values["max_phase_step_waves"].as_f64().unwrap() <= 0.5);
    assert!(d.values["pupil_fit_residual_waves"].as_f64().unwrap() <= 1e-3);
    for key in [
        "fft_grid",
        "native_pitch_x_um",
        "fft_field_x_um",
        "spot_extent_x_um",
        "energy_in_window",
        "pupil_fit_degree",
        "distortion_order",
        "time_s",
    ] {
        assert!(d.values.contains_key(key), "missing {key}");
    }
    assert!(p.data.iter().all(|v| v.is_finite() && *v >= 0.0));

    // Vignetting: a stop smaller than the beam clips rays; the general FFT takes over.
    let mut v = common::paper_triplet_json();
    v["surfaces"][4]["semi_diameter"] = Value::from(1.7);
    let vignetted = Lens::from_json(&v.to_string()).unwrap();
    let p = psf(&vignetted, 14.9, 550.0, &dataset_opts()).unwrap();
    assert_eq!(p.diagnostics.values["fft_mode"], "general");
    assert!(p.diagnostics.values["fast_fallback"]
        .as_str()
        .unwrap()
        .contains("vignetting"));
    assert!(p.diagnostics.values["transmitted_fraction"].as_f64().unwrap() < 0.99);
    // ... and the batch's relative illumination is the general path's (the fine 24-ring
    // grid where vignetting cuts the pupil).
    let b = psf_batch(std::slice::from_ref(&vignetted), &[14.9], &rgb(), &dataset_opts()).unwrap();
    let slow = psf_batch(
        std::slice::from_ref(&vignetted),
        &[14.9],
        &rgb(),
        &PsfOptions {
            fast: false,
            ..dataset_opts()
        },
    )
    .unwrap();
    assert_eq!(b.relative_illumination, slow.relative_illumination);
    assert_eq!(b.psf, slow.psf);

    for o in [
        PsfOptions {
            aiming: psf_engine::Aiming::Real,
            ..dataset_opts()
        },
        PsfOptions {
            integrate: true,
            ..dataset_opts()
        },
    ] {
        let p = psf(&lens, 7.0, 550.0, &o).unwrap();
        assert!(
            !p.diagnostics.values.contains_key("fft_mode"),
            "fast path used with {o:?}"
        );
    }
}
