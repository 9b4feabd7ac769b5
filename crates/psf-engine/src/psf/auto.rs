//! `method = "auto"`: the cheapest PSF method and setting predicted to meet an accuracy
//! target (relative L1 of the PSF against the converged Huygens PSF) for this lens, field
//! and wavelength.
//!
//! A probe traces a 16 x 16 pupil grid (about 200 rays) and measures what decides each
//! method's error:
//! - the pupil's direction-cosine radius `na` (Airy scale lambda / (n na));
//! - the geometric spot's extent about the chief ray;
//! - the largest wavefront step between neighbouring samples, which scales as 1 / N;
//! - vignetting, TIR and missed rays (the fast FFT needs a whole pupil; a sliver needs
//!   more samples);
//! - the pupil map's departure from affine over the window (the FFT's Taylor terms).
//!
//! Each candidate's error is predicted by one model for every sampled method: a sampled
//! pupil repeats the PSF with period D = N lambda / (2 n na) (the FFT field for the fast
//! path), so the error is the diffraction tail that the neighbouring copies put into the
//! window, ~ (lambda / (n na)) / (D - window/2 - spot), plus the quadrature error of the
//! wavefront, ~ step^2, plus a floor (the fast path's fits):
//!
//!   e = a_m tail + b_m step_N^2 + c_m.
//!
//! The geometric PSF (interpolated, no ray noise) lacks diffraction: e = window share x
//! a_g lambda / (n na) / spot_rms, its error over the window counted against the transmitted
//! light (see GEO_A).
//! The constants (`MODELS`) are fitted to the bundled lenses' measured errors
//! (`optix bench auto --calibrate`) times a safety margin, and checked on random designs the
//! fit never saw (tests/test_auto.py, docs/accuracy.md). Costs are op counts times constants
//! fitted to this engine's timings; only their order matters for the choice.

use super::fast::{fast_len, grid_want, MAX_GRID};
use super::fft::{fit_affine, MAX_ORDER, TAYLOR_TOL_RAD};
use super::{factorial, pupil, Diagnostics, Method, PsfOptions};
use crate::aim::Aiming;
use crate::error::Result;
use crate::trace::System;
use crate::Lens;
use serde_json::{json, Value};

pub const PROBE_SAMPLES: usize = 16;
/// Default accuracy target: relative L1 error of the PSF.
pub const DEFAULT_TARGET: f64 = 0.02;

/// What the probe measured.
#[derive(Clone, Debug)]
pub struct Probe {
    pub wavelength_mm: f64,
    pub n_image: f64,
    /// Largest |L - L_chief|, |M - M_chief| over the pupil (image-space numerical aperture).
    pub na: f64,
    /// Largest distance of a probe ray's image point from the chief ray's (mm).
    pub spot_extent_mm: f64,
    /// RMS distance of the image points from their centroid (mm).
    pub spot_rms_mm: f64,
    /// Largest wavefront change between neighbouring samples at PROBE_SAMPLES (waves).
    pub step_waves: f64,
    /// Samples across the transmitted pupil at PROBE_SAMPLES.
    pub samples_across: usize,
    pub transmitted: f64,
    /// Rays lost to vignetting (clipped), or to TIR / missed surfaces.
    pub vignetted: bool,
    pub partial: bool,
    /// Largest departure of (L, M) from the pupil's affine map (direction cosines).
    pub map_residual: f64,
    /// Probe rays (of those transmitted) landing inside the window `window_mm` about the chief
    /// ray, plus one, over the rays transmitted plus one: the share of the light the window
    /// holds, never estimated as zero.
    pub window_fraction: f64,
    /// Reference-sphere radius (mm): decides whether Huygens sums exactly (its cost).
    pub radius_mm: f64,
}

/// A method and setting with its predicted error and cost.
#[derive(Clone, Debug)]
pub struct Candidate {
    pub method: Method,
    pub fast: bool,
    pub pupil_samples: usize,
    pub predicted_error: f64,
    pub predicted_cost_s: f64,
}

/// How a PSF's method and sampling are named in choices and records: "fft-fast N=64"
/// (the direction-grid FFT), "fft N=128", "huygens N=256", "geometric N=128".
pub fn label(method: &str, fast: bool, pupil_samples: usize) -> String {
    format!("{method}{} N={pupil_samples}", if fast { "-fast" } else { "" })
}

impl Candidate {
    pub fn name(&self) -> String {
        label(self.method.name(), self.fast, self.pupil_samples)
    }
}

/// `window_mm`: the PSF window's side (size x pixel), for `Probe::window_fraction`.
pub fn probe(lens: &Lens, field_deg: f64, wavelength_nm: f64, aiming: Aiming, window_mm: f64) -> Result<Probe> {
    let sys = System::new(lens, wavelength_nm)?;
    let p = pupil::sample_pupil(&sys, field_deg, aiming, PROBE_SAMPLES)?;
    let (lc, mc) = (p.chief_dir.x, p.chief_dir.y);
    let (mut na, mut ext, mut n, mut sx, mut sy, mut sxx) = (0.0f64, 0.0f64, 0.0, 0.0, 0.0, 0.0);
    let mut inside = 0.0;
    for j in 0..p.valid.len() {
        if !p.valid[j] {
            continue;
        }
        na = na.max((p.l[j] - lc).abs()).max((p.m[j] - mc).abs());
        let (dx, dy) = (p.image[j].x - p.chief.x, p.image[j].y - p.chief.y);
        ext = ext.max(dx.abs()).max(dy.abs());
        if dx.abs().max(dy.abs()) <= 0.5 * window_mm {
            inside += 1.0;
        }
        n += 1.0;
        sx += dx;
        sy += dy;
        sxx += dx * dx + dy * dy;
    }
    let rms = if n > 0.0 {
        (sxx / n - (sx / n).powi(2) - (sy / n).powi(2)).max(0.0).sqrt()
    } else {
        0.0
    };
    let map = fit_affine(&p);
    let mut resid = 0.0f64;
    for b in 0..p.n {
        for a in 0..p.n {
            let j = b * p.n + a;
            if p.valid[j] {
                let r = (p.l[j] - map.l0 - map.lx * a as f64).abs() + (p.m[j] - map.m0 - map.my * b as f64).abs();
                resid = resid.max(r);
            }
        }
    }
    let [_, missed, clipped, tir, invalid] = p.status_counts;
    let out = Probe {
        wavelength_mm: p.wavelength_mm,
        n_image: p.n_image,
        na,
        spot_extent_mm: ext,
        spot_rms_mm: rms,
        step_waves: p.max_phase_step(),
        samples_across: p.samples_across(),
        transmitted: p.transmitted_fraction(),
        vignetted: clipped > 0,
        partial: missed + tir + invalid > 0,
        map_residual: resid,
        window_fraction: ((inside + 1.0) / (n + 1.0)).min(1.0),
        radius_mm: p.radius,
    };
    pupil::recycle(p);
    Ok(out)
}

/// Error model per method: e = safety (a tail + b step^2 + c). a, b, c: least squares in
/// log error over the tuning set's candidates (the bundled lenses, 27 cases x 3-4
/// settings); safety: the largest ratio of measured to fitted error there.
struct Model {
    a: f64,
    b: f64,
    c: f64,
    safety: f64,
}
const FAST: Model = Model {
    a: 0.052,
    b: 0.124,
    c: 4.5e-4,
    safety: 1.6,
};
const FFT: Model = Model {
    a: 0.106,
    b: 0.362,
    c: 6.5e-4,
    safety: 2.6,
};
const HUYGENS: Model = Model {
    a: 0.209,
    b: 0.225,
    c: 1e-4,
    safety: 1.6,
};
/// Geometric (the interpolated spot, psf/geometric.rs: no ray noise): the light it lacks is
/// diffraction, the ripple and caustic fringes on the scale of the Airy radius, so its error
/// over the window is ~ GEO_A airy / spot_rms. Auto's target for it counts that error
/// against the transmitted energy (the window's error over all the light the lens delivers,
/// docs/accuracy.md "Spots larger than the window"), so it scales with the window's share of
/// the light (`Probe::window_fraction`); plus the pupil rim's staircase, GEO_RIM / N:
///
///   e = GEO_SAFETY window_fraction (GEO_A airy / spot_rms + GEO_RIM / N).
///
/// GEO_A: the largest ratio of measured error to airy / spot_rms on the refused designs of
/// paper-triplet-detect-wide and the defocused Cooke (benches/geometric_accuracy.py).
const GEO_A: f64 = 26.0;
const GEO_RIM: f64 = 1.3;
const GEO_SAFETY: f64 = 1.5;
/// Splatting the interpolated sub-points: per output pixel (about four sub-points each).
const COST_SPLAT: f64 = 2e-8;

impl Model {
    fn error(&self, tail: f64, step: f64) -> f64 {
        self.safety * (self.a * tail + self.b * step * step + self.c)
    }
}
/// Fewest samples across the transmitted pupil (pupil::MIN_SAMPLES_ACROSS, with margin).
const MIN_ACROSS: f64 = 12.0;
/// Cost = per call + per unit of work (seconds), fitted to the tuning set's timings: fast
/// FFT per g^2 log2(g) / 2, general FFT per G^2 log2(G), Huygens per wavelet term (rays x
/// pixels), geometric per ray-surface intersection.
const COST_FAST: (f64, f64) = (1.8e-4, 2.0e-10);
const COST_FFT: (f64, f64) = (4.7e-4, 7.8e-10);
const COST_HUYGENS: (f64, f64) = (2e-3, 3.5e-10);
/// Huygens per wavelet term where it sums exactly (huygens.rs: the cubic term of its distance
/// expansion over the window above CUBIC_TOL_RAD, e.g. the paper triplet over a 246 um window
/// at 1 um): 18.5 s for N = 128 at 10 deg against 0.27 s predicted with COST_HUYGENS
/// (measured 2026-11-27 on the shared 2-core machine, 2 threads).
const COST_HUYGENS_EXACT: f64 = 2.4e-8;
const COST_GEO: (f64, f64) = (2.1e-4, 8.4e-9);

/// The fast path's fewest cells across the pupil. Above 256 they matter where the spot sizes
/// the grid (its period holds twice the spot): more cells make the steps of a wavefront of
/// tens of waves finer (benches/auto_flagged.py: 2.7 % at the spot-sized grid, 0.71 % at 512
/// cells, on a 16 %-of-the-light window). 1024 at most: a traced pupil keeps about 100 bytes
/// a cell.
const FAST_N: [usize; 5] = [64, 128, 256, 512, 1024];
const FFT_N: [usize; 4] = [32, 64, 128, 256];
const HUYGENS_N: [usize; 3] = [64, 128, 256];
const GEO_N: [usize; 3] = [64, 128, 256];

/// The diffraction tail that copies of the PSF at period `period` put into the window.
fn tail(pr: &Probe, period_mm: f64, o: &PsfOptions) -> f64 {
    let airy = pr.wavelength_mm / (pr.n_image * pr.na.max(1e-6));
    let clear = period_mm - 0.5 * o.size as f64 * o.pixel_mm - pr.spot_extent_mm;
    if clear <= airy {
        return 1.0;
    }
    (airy / clear).min(1.0)
}

/// Every candidate with its predicted error and cost, cheapest first.
pub fn candidates(pr: &Probe, o: &PsfOptions, n_surfaces: usize) -> Vec<Candidate> {
    let mut out = vec![];
    let lam = pr.wavelength_mm / pr.n_image;
    let na = pr.na.max(1e-6);
    let step = |n: usize| pr.step_waves * PROBE_SAMPLES as f64 / n as f64;
    let across_ok = |n: usize| pr.samples_across as f64 * n as f64 / PROBE_SAMPLES as f64 >= MIN_ACROSS;
    let rays = |n: usize| 0.785 * (n * n) as f64;
    // The general FFT's Taylor expansion must converge over the window.
    let half = (o.size as f64 / 2.0 + 0.5) * o.pixel_mm;
    let eps = 2.0 * std::f64::consts::PI / lam * pr.map_residual * half;
    let taylor_ok = eps.powi(MAX_ORDER as i32 + 1) / factorial(MAX_ORDER + 1) <= TAYLOR_TOL_RAD;
    let fast_ok = o.aiming == Aiming::Paraxial && !o.integrate && o.fft_grid.is_none() && !pr.vignetted && !pr.partial;
    if fast_ok {
        for n in FAST_N {
            // The grid rule of psf/fast.rs: N cells across the pupil, the spot and twice the window.
            let g = fast_len(grid_want(n, pr.wavelength_mm, pr.n_image, 2.0 * na, pr.spot_extent_mm, o) as usize);
            if g > MAX_GRID {
                continue; // the fast path refuses such a grid (and would fall back)
            }
            let cells = 2.0 * na * g as f64 * o.pixel_mm / lam;
            let e = FAST.error(tail(pr, g as f64 * o.pixel_mm, o), step(cells as usize));
            let cost = COST_FAST.0 + COST_FAST.1 * (g * g) as f64 * (g as f64).log2() * 0.5;
            out.push(Candidate {
                method: Method::Fft,
                fast: true,
                pupil_samples: n,
                predicted_error: e,
                predicted_cost_s: cost,
            });
        }
    }
    for n in FFT_N {
        let period = n as f64 * lam / (2.0 * na);
        let ok = taylor_ok && across_ok(n);
        let e = if ok {
            FFT.error(tail(pr, period, o), step(n))
        } else {
            f64::INFINITY
        };
        let want = (2.0 * (o.size as f64 * o.pixel_mm * 0.5 + pr.spot_extent_mm) / o.pixel_mm).ceil() as usize;
        let g = (4 * n).max(want.next_power_of_two()).min(8192.max(4 * n));
        let cost = COST_FFT.0 + COST_FFT.1 * (g * g) as f64 * (g as f64).log2();
        out.push(Candidate {
            method: Method::Fft,
            fast: false,
            pupil_samples: n,
            predicted_error: e,
            predicted_cost_s: cost,
        });
    }
    // Whether the Huygens sum is exact over this window (its separable form's cubic bound).
    let dmax = (o.size as f64 / 2.0 + 0.5) * o.pixel_mm * std::f64::consts::SQRT_2;
    let cubic = 2.0 * std::f64::consts::PI / lam * dmax.powi(3) / (2.0 * pr.radius_mm * pr.radius_mm);
    let per_term = if cubic > super::huygens::CUBIC_TOL_RAD {
        COST_HUYGENS_EXACT
    } else {
        COST_HUYGENS.1
    };
    if !o.integrate {
        for n in HUYGENS_N {
            let period = n as f64 * lam / (2.0 * na);
            let e = if across_ok(n) {
                HUYGENS.error(tail(pr, period, o), step(n))
            } else {
                f64::INFINITY
            };
            let cost = COST_HUYGENS.0 + per_term * rays(n) * (o.size * o.size) as f64;
            out.push(Candidate {
                method: Method::Huygens,
                fast: false,
                pupil_samples: n,
                predicted_error: e,
                predicted_cost_s: cost,
            });
        }
    }
    let airy = lam / na;
    for n in GEO_N {
        let e = GEO_SAFETY * pr.window_fraction * (GEO_A * airy / pr.spot_rms_mm.max(1e-9) + GEO_RIM / n as f64);
        let cost =
            COST_GEO.0 + COST_GEO.1 * rays(n) * (n_surfaces as f64 + 1.0) + COST_SPLAT * (o.size * o.size) as f64;
        out.push(Candidate {
            method: Method::Geometric,
            fast: false,
            pupil_samples: n,
            predicted_error: e,
            predicted_cost_s: cost,
        });
    }
    out.sort_by(|a, b| a.predicted_cost_s.total_cmp(&b.predicted_cost_s));
    out
}

/// The cheapest candidate predicted to meet `target`; where none is, the one predicted
/// most accurate (and `false`).
pub fn choose(cands: &[Candidate], target: f64) -> (Candidate, bool) {
    if let Some(c) = cands.iter().find(|c| c.predicted_error <= target) {
        return (c.clone(), true);
    }
    let best = cands
        .iter()
        .min_by(|a, b| a.predicted_error.total_cmp(&b.predicted_error))
        .expect("candidates");
    (best.clone(), false)
}

/// Single-thread seconds the cost model predicts for one PSF of these options (method and
/// sampling fixed; the general FFT's grid taken as fft_grid or 4 x pupil_samples, its least),
/// so that a long request can say up front what it will take. None for method auto.
pub fn predicted_seconds(o: &PsfOptions, n_surfaces: usize) -> Option<f64> {
    let n = o.pupil_samples as f64;
    let rays = 0.785 * n * n;
    match o.method {
        Method::Huygens => Some(COST_HUYGENS.0 + COST_HUYGENS.1 * rays * (o.size * o.size) as f64),
        Method::Fft => {
            let g = o.fft_grid.unwrap_or(4 * o.pupil_samples) as f64;
            Some(COST_FFT.0 + COST_FFT.1 * g * g * g.log2())
        }
        Method::Geometric => Some(COST_GEO.0 + COST_GEO.1 * rays * (n_surfaces as f64 + 1.0)),
        Method::Auto => None,
    }
}

/// After `failed` (labels) failed its checks: the cheapest untried candidate predicted at
/// least as accurate as `c` (or, where none is, the most accurate untried one).
pub fn escalate(cands: &[Candidate], c: &Candidate, failed: &[String]) -> Option<Candidate> {
    let untried = |k: &&Candidate| !failed.contains(&label(k.method.name(), k.fast, k.pupil_samples));
    let finite = |k: &&Candidate| k.predicted_error.is_finite();
    cands
        .iter()
        .filter(untried)
        .filter(finite)
        .find(|k| k.predicted_error <= c.predicted_error.max(0.0) && k.predicted_cost_s >= c.predicted_cost_s)
        .or_else(|| {
            cands
                .iter()
                .filter(untried)
                .filter(finite)
                .min_by(|a, b| a.predicted_error.total_cmp(&b.predicted_error))
        })
        .cloned()
}

/// Largest wavefront step between pupil samples (waves) that `flagged` lets pass: the error
/// models take steps up to about this far (their b step^2 term); beyond it the sampled
/// pupil aliases whatever the model said.
pub const FLAG_STEP_WAVES: f64 = 1.0;

/// Why a PSF computed for candidate `c` is not the one the model predicted, from its own
/// diagnostics: the fast path fell back to the general FFT (at a sampling nobody chose),
/// the general FFT warned that its Taylor expansion or its field fails over the window, or
/// the pupil is undersampled by more than FLAG_STEP_WAVES. None where nothing flags it.
pub fn flagged(d: &Diagnostics, c: &Candidate) -> Option<String> {
    if c.method == Method::Geometric {
        return None;
    }
    if c.fast {
        if let Some(why) = d.values.get("fast_fallback").and_then(Value::as_str) {
            return Some(format!("the fast path fell back ({why})"));
        }
    }
    let step = d
        .values
        .get("max_phase_step_waves")
        .and_then(Value::as_f64)
        .unwrap_or(0.0);
    if step > FLAG_STEP_WAVES {
        return Some(format!("pupil undersampled ({step:.2} waves between samples)"));
    }
    const FATAL: [&str; 3] = [
        "exit pupil too distorted",
        "energy wraps around",
        "exceeds the FFT field",
    ];
    d.warnings
        .iter()
        .find(|w| FATAL.iter().any(|f| w.contains(f)))
        .map(|w| w.split(':').next().unwrap_or(w).to_string())
}

/// Records the choice, the probe and the target in the PSF's diagnostics.
pub fn record(d: &mut Diagnostics, c: &Candidate, met: bool, pr: &Probe, target: f64, probe_s: f64) {
    d.set("requested_method", "auto");
    d.set(
        "auto",
        json!({
            "target_rel_l1": target,
            "choice": c.name(),
            "method": c.method.name(),
            "fast": c.fast,
            "pupil_samples": c.pupil_samples,
            "predicted_rel_l1": finite(c.predicted_error),
            "predicted_cost_s": c.predicted_cost_s,
            "probe_s": probe_s,
            "probe": probe_json(pr),
        }),
    );
    if !met {
        d.warn(format!(
            "auto: no method is predicted to meet the accuracy target {:.2}% (relative L1); used the most accurate, {} (predicted {:.2}%)",
            100.0 * target,
            c.name(),
            100.0 * c.predicted_error
        ));
    }
}

pub fn probe_json(pr: &Probe) -> Value {
    json!({
        "na": pr.na, "spot_extent_um": pr.spot_extent_mm * 1e3, "spot_rms_um": pr.spot_rms_mm * 1e3,
        "probe_samples": PROBE_SAMPLES as f64, "step_waves": pr.step_waves, "samples_across": pr.samples_across as f64,
        "transmitted_fraction": pr.transmitted, "vignetted": pr.vignetted, "partial": pr.partial,
        "map_residual": pr.map_residual, "window_fraction": pr.window_fraction,
    })
}

pub fn candidate_json(c: &Candidate) -> Value {
    json!({"name": c.name(), "method": c.method.name(), "fast": c.fast, "pupil_samples": c.pupil_samples,
           "predicted_rel_l1": finite(c.predicted_error), "predicted_cost_s": c.predicted_cost_s})
}

fn finite(x: f64) -> Value {
    if x.is_finite() {
        Value::from(x)
    } else {
        Value::Null
    }
}
