//! The one-pass gradient of a design's PSF set (`gradient::psf_set_vjp`): fields x RGB
//! channels of two or one wavelengths each, normalized per channel, binned to sensor pixels,
//! the relative illumination, `auto` choosing each PSF's method, the image plane at the best
//! focus; against Richardson central differences of the engine's own set of the perturbed
//! and refocused lens (`rgb::psf_rgb`, `focus::best_focus_shift`).
use crate::common;
use psf_engine::focus::best_focus_shift;
use psf_engine::gradient::{psf_set_vjp, FocusRule};
use psf_engine::psf::{Method, PsfOptions};
use psf_engine::rgb::{method_used, psf_rgb, Channels, SensorBinning};
use psf_engine::tangent::{perturbed, Param};
use psf_engine::{Aiming, Lens};

fn channels() -> Channels {
    vec![
        vec![(610.0, 0.5), (650.0, 0.5)],
        vec![(550.0, 1.0)],
        vec![(460.0, 0.6), (480.0, 0.4)],
    ]
}

fn opts() -> PsfOptions {
    PsfOptions {
        method: Method::Auto,
        pixel_mm: 1e-3,
        size: 96,
        pupil_samples: 64,
        fast: true,
        ..Default::default()
    }
}

fn rule() -> FocusRule {
    FocusRule {
        fields: vec![0.0, 7.0, 14.9],
        wavelengths: vec![(460.0, 1.0), (550.0, 1.0), (650.0, 1.0)],
        rings: 4,
    }
}

/// `lens` with its image plane at the best focus of `rule`.
fn refocused(lens: &Lens) -> Lens {
    let r = rule();
    let dz = best_focus_shift(lens, &r.fields, &r.wavelengths, r.rings, Aiming::Paraxial).unwrap();
    perturbed(lens, Param::Thickness(lens.surfaces.len() - 1), dz).unwrap()
}

fn random(n: usize, seed: u64) -> Vec<f64> {
    let mut x = seed;
    (0..n)
        .map(|_| {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        })
        .collect()
}

#[test]
fn the_sensor_binnings_adjoint_is_its_transpose() {
    let b = SensorBinning::new(96, 1e-3, 16, 5.86e-3).unwrap();
    let (x, g) = (random(96 * 96, 1), random(16 * 16, 2));
    let mut bx = vec![0.0f32; 16 * 16];
    b.apply(&x, 1.0, &mut bx);
    let mut btg = vec![0.0; 96 * 96];
    b.apply_adjoint(&g, &mut btg);
    let lhs: f64 = g.iter().zip(&bx).map(|(a, b)| a * *b as f64).sum();
    let rhs: f64 = btg.iter().zip(&x).map(|(a, b)| a * b).sum();
    assert!(
        (lhs - rhs).abs() < 1e-5 * rhs.abs().max(1.0),
        "<g, Bx> {lhs} vs <B^T g, x> {rhs}"
    );
}

#[test]
fn the_design_gradient_matches_central_differences_of_the_refocused_psf_set() {
    let lens = refocused(&common::paper_triplet_unclipped());
    // the e2e space's radii, conics and gaps, one aspheric term, the f-number
    let params: Vec<Param> = common::e2e_params()[..9]
        .iter()
        .copied()
        .chain([Param::Aspheric(5, 1), Param::FNumber])
        .collect();
    let steps = [4e-3, 1e-3, 2e-3, 1e-3, 1e-3, 1e-3, 3e-2, 1e-3, 2.5e-4, 1e-8, 1e-3];
    let fields = [0.0, 10.0, 14.9];
    let (o, ch) = (opts(), channels());
    let bin = SensorBinning::new(o.size, o.pixel_mm, 16, 5.86e-3).unwrap();
    let (nf, nc) = (fields.len(), ch.len());
    let g_psf = random(nf * nc * 16 * 16, 7);
    let g_ri = random(nf * nc, 8);
    let r = psf_set_vjp(
        &lens,
        &fields,
        &ch,
        &o,
        Some(&bin),
        &params,
        Some(&rule()),
        &g_psf,
        &g_ri,
    )
    .unwrap();
    assert!(r.fallback.is_none(), "{:?}", r.fallback);
    // dL/d(unit-sum fine PSFs): the binning's transpose (checked above)
    let g_fine: Vec<Vec<f64>> = g_psf
        .chunks_exact(256)
        .map(|g| {
            let mut out = vec![0.0; o.size * o.size];
            bin.apply_adjoint(g, &mut out);
            out
        })
        .collect();
    let set = |l: &Lens| -> (f64, Vec<String>, Vec<f64>) {
        let (mut loss, mut used, mut psf) = (0.0, vec![], vec![]);
        for (k, &f) in fields.iter().enumerate() {
            let p = psf_rgb(l, f, &ch, &o).unwrap();
            used.extend(p.diagnostics.iter().map(method_used));
            for c in 0..nc {
                let data = &p.data[c * o.size * o.size..][..o.size * o.size];
                loss += g_fine[k * nc + c].iter().zip(data).map(|(a, b)| a * b).sum::<f64>();
                loss += g_ri[k * nc + c] * p.relative_illumination[c];
            }
            psf.extend(p.data);
        }
        (loss, used, psf)
    };
    let (_, used0, psf0) = set(&lens);
    assert!(used0.iter().all(|m| m.starts_with("fft-fast")), "{used0:?}");
    let worst = psf0.iter().zip(&r.psf).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        worst < 1e-12,
        "the gradient's PSF set differs from psf_rgb's by {worst:e}"
    );
    let (mut num, mut den) = (0.0, 0.0);
    for (k, (&p, &h)) in params.iter().zip(&steps).enumerate() {
        let cd = |h: f64| {
            let (a, ua, _) = set(&refocused(&perturbed(&lens, p, h).unwrap()));
            let (b, ub, _) = set(&refocused(&perturbed(&lens, p, -h).unwrap()));
            assert!(ua == used0 && ub == used0, "{p:?}: auto chose differently");
            (a - b) / (2.0 * h)
        };
        let fd = (4.0 * cd(0.5 * h) - cd(h)) / 3.0;
        eprintln!("{p:?}: gradient {:.6e} differences {fd:.6e}", r.grad[k]);
        num += (r.grad[k] - fd).powi(2);
        den += fd * fd;
    }
    let rel = (num / den).sqrt();
    eprintln!("relative error of J^T g over the set: {rel:.2e}");
    assert!(rel < 5e-3, "relative error {rel:e}");
}
