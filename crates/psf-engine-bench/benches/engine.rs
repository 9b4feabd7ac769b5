//! Criterion benchmarks of the core: ray throughput through the Cooke triplet at full
//! field, FFT PSF (64 pupil samples, 256 grid) and Huygens PSF (64 samples, 128x128), and
//! the dataset batch (paper-triplet-v1, 13 fields x 3 channels, 128 x 128 at 1 um).
//! Uses the reference Cooke triplet in ../shared/reference and the bundled paper-triplet-v1 (crates/psf-engine/tests/common).

#[path = "../../psf-engine/tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use psf_engine::psf::{psf, Method, PsfOptions};
use psf_engine::rgb::psf_batch;
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

criterion_group!(benches, bench_trace, bench_psf, bench_dataset);
criterion_main!(benches);
