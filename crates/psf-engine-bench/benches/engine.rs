//! Criterion benchmarks of the core: ray throughput through the Cooke triplet at full
//! field, FFT PSF (64 pupil samples, 256 grid) and Huygens PSF (64 samples, 128x128), and
//! the dataset batch (paper-triplet-v1, 13 fields x 3 channels, 128 x 128 at 1 um), and the
//! lens gradient of one design's PSF set (the e2e dataset's settings): the forward set, its
//! one-pass vector-Jacobian product, and the Jacobian by central differences (2P + 1
//! designs), on the triplet (P = 19) and the eight-element lens (P = 20).
//! Uses the reference Cooke triplet in ../shared/reference and the bundled paper-triplet-v1 (crates/psf-engine/tests/common).

#[path = "../../psf-engine/tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use psf_engine::gradient::{psf_set_vjp, FocusRule};
use psf_engine::psf::{psf, Method, PsfOptions};
use psf_engine::rgb::{psf_batch, psf_batch_into, SensorBinning};
use psf_engine::tangent::Param;
use psf_engine::{Aiming, Beam, System};
use std::hint::black_box;

fn bench_trace(c: &mut Criterion) {
    let lens = common::cooke();
    let sys = System::new(&lens, 550.0).unwrap();
    let beam = Beam::new(&sys, 20.0, Aiming::Paraxial).unwrap();
    let n = 200_000;
    let side = (n as f64).sqrt() as usize;
    let (mut o, mut d) = (vec![], vec![]);
    for i in 0..side * side {
        let (a, b) = (
            (i % side) as f64 / side as f64 * 2.0 - 1.0,
            (i / side) as f64 / side as f64 * 2.0 - 1.0,
        );
        o.push(beam.launch(a * 0.7, b * 0.7).origin);
        d.push(beam.launch(a * 0.7, b * 0.7).dir);
    }
    let mut g = c.benchmark_group("trace");
    g.throughput(Throughput::Elements(o.len() as u64));
    g.bench_function("cooke_20deg", |bch| bch.iter(|| black_box(sys.trace_many(&o, &d))));
    // What the Python bench measures: 1e6 pupil points, launched and traced into flat arrays.
    let n = 1_000_000;
    let (px, py): (Vec<f64>, Vec<f64>) = (0..n)
        .map(|i| {
            let (r, t) = (
                ((i as f64 * 0.618_034) % 1.0).sqrt(),
                (i as f64 * 0.754_877_666) % 1.0 * std::f64::consts::TAU,
            );
            (r * t.cos(), r * t.sin())
        })
        .unzip();
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(20);
    g.bench_function("cooke_20deg_pupil_1e6", |bch| {
        bch.iter(|| black_box(beam.trace_pupil_soa(&px, &py)))
    });
    g.finish();
}

fn bench_psf(c: &mut Criterion) {
    let lens = common::cooke();
    let mut g = c.benchmark_group("psf");
    g.sample_size(20);
    for field in [0.0, 20.0] {
        let fft = PsfOptions {
            method: Method::Fft,
            pupil_samples: 64,
            fft_grid: Some(256),
            size: 64,
            pixel_mm: 1e-3,
            ..Default::default()
        };
        g.bench_function(format!("fft_64_256_{field}deg"), |b| {
            b.iter(|| black_box(psf(&lens, field, 550.0, &fft).unwrap()))
        });
        let huy = PsfOptions {
            method: Method::Huygens,
            pupil_samples: 64,
            size: 128,
            pixel_mm: 0.5e-3,
            ..Default::default()
        };
        g.bench_function(format!("huygens_64_128_{field}deg"), |b| {
            b.iter(|| black_box(psf(&lens, field, 550.0, &huy).unwrap()))
        });
    }
    g.finish();
}

/// The dataset generator's call: designs x 13 fields (0-14.9 deg) x R/G/B (650/550/470 nm),
/// 128 x 128 pixels at 1 um, point sampling, fast path, pupil_samples 64; throughput in
/// designs (the batch runs on every thread of the pool).
fn bench_dataset(c: &mut Criterion) {
    let nd = 16;
    let lenses = vec![common::paper_triplet(); nd];
    let fields: Vec<f64> = (0..13).map(|i| 14.9 * i as f64 / 12.0).collect();
    let ch = vec![vec![(650.0, 1.0)], vec![(550.0, 1.0)], vec![(470.0, 1.0)]];
    let o = PsfOptions {
        method: Method::Fft,
        pupil_samples: 64,
        size: 128,
        pixel_mm: 1e-3,
        fast: true,
        ..Default::default()
    };
    let mut g = c.benchmark_group("dataset");
    g.sample_size(10);
    g.throughput(Throughput::Elements(nd as u64));
    g.bench_function("paper_triplet_13x3", |b| {
        b.iter(|| black_box(psf_batch(&lenses, &fields, &ch, &o).unwrap()))
    });
    g.finish();
    // Designs per second, printed plainly (criterion reports elements/s as well).
    let t = std::time::Instant::now();
    let reps = 5;
    for _ in 0..reps {
        black_box(psf_batch(&lenses, &fields, &ch, &o).unwrap());
    }
    let dt = t.elapsed().as_secs_f64() / reps as f64;
    println!(
        "dataset/paper_triplet_13x3: {:.1} designs/s on {} threads ({:.0} us per PSF of wall time)",
        nd as f64 / dt,
        rayon::current_num_threads(),
        dt * 1e6 / (nd * 39) as f64
    );
}

/// One design's PSF set on the e2e dataset's terms, and its gradient's inputs.
struct GradientCase {
    name: &'static str,
    lens: psf_engine::Lens,
    /// The PSF options and the sensor binning's size (its dataset's window).
    o: PsfOptions,
    m: usize,
    fields: Vec<f64>,
    params: Vec<Param>,
    rule: FocusRule,
}

fn gradient_cases() -> Vec<GradientCase> {
    use psf_engine::focus::best_focus_shift;
    let refocus = |lens: psf_engine::Lens, rule: &FocusRule| {
        let dz = best_focus_shift(&lens, &rule.fields, &rule.wavelengths, rule.rings, Aiming::Paraxial).unwrap();
        let last = lens.surfaces.len() - 1;
        psf_engine::tangent::perturbed(&lens, Param::Thickness(last), dz).unwrap()
    };
    let fields = |max: f64| -> Vec<f64> { (0..13).map(|i| max * i as f64 / 12.0).collect() };
    let rule = |f: &[f64]| FocusRule {
        fields: f.iter().step_by(2).copied().collect(),
        wavelengths: vec![(470.0, 1.0), (550.0, 1.0), (650.0, 1.0)],
        rings: 4,
    };
    // the paper triplet as the dataset traces it (no clear apertures), the e2e space's 19
    let f3 = fields(14.9);
    let r3 = rule(&f3);
    let p3 = common::e2e_params();
    let triplet = refocus(common::paper_triplet_unclipped(), &r3);
    // the eight-element lens (unclipped), its space's 14 radii and 6 gaps
    let f8 = fields(23.94);
    let r8 = rule(&f8);
    let mut p8: Vec<Param> = [0, 1, 2, 3, 4, 5, 6, 8, 9, 10, 11, 12, 13, 14]
        .map(Param::Radius)
        .to_vec();
    p8.extend([1, 3, 6, 7, 10, 12].map(Param::Thickness));
    let eight = refocus(common::fixture_lens("apo_gauss_8e"), &r8);
    let o = |size: usize, pixel_mm: f64| PsfOptions {
        method: Method::Auto,
        pupil_samples: 64,
        size,
        pixel_mm,
        fast: true,
        ..Default::default()
    };
    vec![
        GradientCase {
            name: "paper_triplet",
            lens: triplet,
            o: o(123, 2e-3),
            m: 41,
            fields: f3,
            params: p3,
            rule: r3,
        },
        GradientCase {
            name: "apo_gauss_8e",
            lens: eight,
            o: o(64, 1e-3),
            m: 9,
            fields: f8,
            params: p8,
            rule: r8,
        },
    ]
}

/// A parameter's value in the lens.
fn param_value(lens: &psf_engine::Lens, p: Param) -> f64 {
    match p {
        Param::Curvature(i) => lens.surfaces[i].curvature,
        Param::Radius(i) => 1.0 / lens.surfaces[i].curvature,
        Param::Conic(i) => lens.surfaces[i].conic,
        Param::Aspheric(i, k) => lens.surfaces[i].aspheric[k],
        Param::Thickness(i) => lens.surfaces[i].thickness,
        Param::FNumber | Param::Epd => 1.0,
    }
}

fn bench_gradient(c: &mut Criterion) {
    let ch = vec![vec![(650.0, 1.0)], vec![(550.0, 1.0)], vec![(470.0, 1.0)]];
    let mut g = c.benchmark_group("gradient");
    g.sample_size(10);
    let mut per_psf = vec![];
    for case in gradient_cases() {
        let (o, m) = (&case.o, case.m);
        let bin = SensorBinning::new(o.size, o.pixel_mm, m, 5.86e-3).unwrap();
        let (nf, nc) = (case.fields.len(), ch.len());
        let g_psf: Vec<f64> = (0..nf * nc * m * m)
            .map(|i| ((i * 7919) % 1000) as f64 / 500.0 - 1.0)
            .collect();
        let g_ri = vec![0.5; nf * nc];
        let mut sensor = vec![0.0f32; nf * nc * m * m];
        let mut out = vec![0.0f32; nf * nc * o.size * o.size];
        let forward = |out: &mut [f32], sensor: &mut [f32]| {
            psf_batch_into(
                std::slice::from_ref(&case.lens),
                &case.fields,
                &ch,
                o,
                out,
                Some((&bin, sensor)),
            )
            .unwrap()
        };
        let vjp = || {
            let r = psf_set_vjp(
                &case.lens,
                &case.fields,
                &ch,
                o,
                Some(&bin),
                &case.params,
                Some(&case.rule),
                &g_psf,
                &g_ri,
            )
            .unwrap();
            assert!(r.fallback.is_none(), "{}: {:?}", case.name, r.fallback);
            r
        };
        // the Jacobian by differences: 2P + 1 designs in one batch (steps of 1e-4 of each value)
        let p = case.params.len();
        let designs: Vec<psf_engine::Lens> = std::iter::once(case.lens.clone())
            .chain(case.params.iter().flat_map(|&q| {
                let h = 1e-4 * param_value(&case.lens, q).abs().max(1e-8);
                [h, -h].map(|h| psf_engine::tangent::perturbed(&case.lens, q, h).unwrap())
            }))
            .collect();
        let mut jout = vec![0.0f32; designs.len() * nf * nc * o.size * o.size];
        let mut jsensor = vec![0.0f32; designs.len() * nf * nc * m * m];
        g.bench_function(format!("{}_forward_13x3", case.name), |b| {
            b.iter(|| black_box(forward(&mut out, &mut sensor)))
        });
        g.bench_function(format!("{}_vjp_13x3_p{p}", case.name), |b| b.iter(|| black_box(vjp())));
        g.bench_function(format!("{}_differences_13x3_p{p}", case.name), |b| {
            b.iter(|| {
                black_box(
                    psf_batch_into(&designs, &case.fields, &ch, o, &mut jout, Some((&bin, &mut jsensor))).unwrap(),
                )
            })
        });
        // the ratios, printed plainly (median of 5 of each, in turn)
        let time = |f: &mut dyn FnMut()| {
            let mut t: Vec<f64> = (0..5)
                .map(|_| {
                    let t0 = std::time::Instant::now();
                    f();
                    t0.elapsed().as_secs_f64()
                })
                .collect();
            t.sort_by(f64::total_cmp);
            t[2]
        };
        let tf = time(&mut || {
            black_box(forward(&mut out, &mut sensor));
        });
        let tv = time(&mut || {
            black_box(vjp());
        });
        let td = time(&mut || {
            black_box(psf_batch_into(&designs, &case.fields, &ch, o, &mut jout, Some((&bin, &mut jsensor))).unwrap());
        });
        println!(
            "gradient/{}: forward set {:.1} ms, one-pass VJP {:.1} ms ({:.2}x the forward), differences ({} designs) {:.1} ms ({:.1}x the VJP), P = {p}, {} threads",
            case.name,
            tf * 1e3,
            tv * 1e3,
            tv / tf,
            designs.len(),
            td * 1e3,
            td / tv,
            rayon::current_num_threads()
        );
        per_psf.push((case.name, tv / (nf * nc) as f64));
    }
    g.finish();
    println!(
        "gradient: VJP per PSF {} {:.2} ms, {} {:.2} ms ({:.2}x)",
        per_psf[1].0,
        per_psf[1].1 * 1e3,
        per_psf[0].0,
        per_psf[0].1 * 1e3,
        per_psf[1].1 / per_psf[0].1
    );
}

criterion_group!(benches, bench_trace, bench_psf, bench_dataset, bench_gradient);
criterion_main!(benches);
