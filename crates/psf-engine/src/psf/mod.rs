//! Point spread functions for one field angle (along +y) and wavelength, each returned
//! with its diagnostics: the sampling checks made and warnings where the result cannot be
//! trusted. Output convention: row = image y, column = image x, pixel (size/2, size/2)
//! centred on the chief-ray image point, each pixel the fraction of the entrance-pupil
//! flux landing in it.

pub mod auto;
pub mod fast;
pub mod fast_adjoint;
pub mod fft;
pub mod geometric;
pub mod huygens;
pub mod pupil;
pub mod resample;
pub mod traced;

use crate::aim::Aiming;
use crate::error::{arg, EngineError, Result};
use crate::trace::System;
use crate::Lens;
use serde_json::{Map, Value};
use std::time::Instant;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    Geometric,
    Fft,
    Huygens,
    /// The cheapest of the three (and its sampling) predicted to meet
    /// `PsfOptions::accuracy` (psf/auto.rs); resolved per lens, field and wavelength.
    Auto,
}

impl std::str::FromStr for Method {
    type Err = EngineError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "geometric" => Ok(Method::Geometric),
            "fft" => Ok(Method::Fft),
            "huygens" => Ok(Method::Huygens),
            "auto" => Ok(Method::Auto),
            _ => arg(format!(
                "method must be \"auto\", \"geometric\", \"fft\" or \"huygens\", got \"{s}\""
            )),
        }
    }
}

impl Method {
    pub fn name(&self) -> &'static str {
        match self {
            Method::Geometric => "geometric",
            Method::Fft => "fft",
            Method::Huygens => "huygens",
            Method::Auto => "auto",
        }
    }
}

#[derive(Clone, Debug)]
pub struct PsfOptions {
    pub method: Method,
    /// Output pixel pitch (mm).
    pub pixel_mm: f64,
    /// Output size (pixels per side).
    pub size: usize,
    /// Pupil samples across the diameter (FFT / Huygens); rays across for geometric.
    pub pupil_samples: usize,
    /// FFT grid (default 4 x pupil_samples).
    pub fft_grid: Option<usize>,
    pub aiming: Aiming,
    /// Huygens: evaluate the exact distance for every pixel (slow; for validation).
    pub huygens_exact: bool,
    /// Pixel values: false = intensity at the pixel centre x pixel area (default, what a
    /// super-resolved PSF needs); true = energy integrated over the pixel area (what a
    /// detector pixel collects; the geometric method always integrates; Huygens refuses).
    pub integrate: bool,
    /// FFT method: compute on a grid of direction cosines whose FFT lands on the output
    /// pixels (psf/fast.rs) wherever that applies (paraxial aiming, point sampling, no
    /// fixed fft_grid, no vignetting), else the general FFT. `pupil_samples` is then the
    /// least number of grid cells across the pupil. Off by default here; the RGB and batch
    /// bindings turn it on.
    pub fast: bool,
    /// method = auto: the accuracy target, relative L1 error of the PSF.
    pub accuracy: f64,
    /// Where a caller watches a long computation (Huygens): work done, and a stop request.
    pub progress: Option<std::sync::Arc<Progress>>,
}

/// Progress of a long PSF computation: `done` of `total` work units (the Huygens sum counts
/// image rows or row blocks), and `cancel`, which the computation checks between units.
#[derive(Debug, Default)]
pub struct Progress {
    pub done: std::sync::atomic::AtomicU64,
    pub total: std::sync::atomic::AtomicU64,
    pub cancel: std::sync::atomic::AtomicBool,
}

impl Progress {
    pub fn start(&self, total: usize) {
        self.total.store(total as u64, std::sync::atomic::Ordering::Relaxed);
    }
    pub fn step(&self) {
        self.done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }
    pub fn cancelled(&self) -> bool {
        self.cancel.load(std::sync::atomic::Ordering::Relaxed)
    }
}

impl Default for PsfOptions {
    fn default() -> Self {
        PsfOptions {
            method: Method::Fft,
            pixel_mm: 1e-3,
            size: 64,
            pupil_samples: 64,
            fft_grid: None,
            aiming: Aiming::Paraxial,
            huygens_exact: false,
            integrate: false,
            fast: false,
            accuracy: auto::DEFAULT_TARGET,
            progress: None,
        }
    }
}

impl PsfOptions {
    /// What one PSF of these options allocates, at least: the output and its resampling
    /// buffers (f64), the FFT grid (complex f64, with its scratch; the general FFT's grid is
    /// at least 4 x pupil_samples across) and the sampled pupil.
    pub fn memory(&self) -> crate::budget::Need {
        let out = (self.size * self.size) as f64 * 8.0 * 3.0;
        let fast = self.fast && self.method == Method::Fft && self.fft_grid.is_none();
        // The fast path's fallback runs the general FFT at most at FALLBACK_SAMPLES.
        let n = if fast {
            self.pupil_samples.min(fast::FALLBACK_SAMPLES)
        } else {
            self.pupil_samples
        };
        let g = self.fft_grid.unwrap_or(4 * n) as f64;
        let fft = if self.method == Method::Fft {
            g * g * 16.0 * 2.0
        } else {
            0.0
        };
        let pupil = (n as f64).powi(2) * 96.0;
        // The fast path's direction cells (single-precision rows, and a traced pupil's
        // per-cell state: about 100 bytes a cell over the pupil's N^2 cells).
        let cells = if fast {
            (self.pupil_samples as f64).powi(2) * 100.0
        } else {
            0.0
        };
        crate::budget::Need(vec![
            ("output".into(), out),
            (format!("FFT grid {g}^2"), fft),
            ("pupil".into(), pupil),
            ("direction cells".into(), cells),
        ])
    }

    pub fn check(&self) -> Result<()> {
        if !(self.pixel_mm.is_finite() && self.pixel_mm > 0.0) {
            return arg(format!("pixel pitch {} um must be positive", self.pixel_mm * 1e3));
        }
        if self.size < 2 || self.size > 8192 {
            return arg(format!("size {} must be within 2..8192", self.size));
        }
        if self.pupil_samples < 4 || self.pupil_samples > 4096 {
            return arg(format!("pupil_samples {} must be within 4..4096", self.pupil_samples));
        }
        if !(self.accuracy.is_finite() && self.accuracy > 0.0) {
            return arg(format!(
                "accuracy target {} must be a positive relative L1 error (e.g. 0.02)",
                self.accuracy
            ));
        }
        if let Some(g) = self.fft_grid {
            if !(4..=65536).contains(&g) {
                return arg(format!("fft_grid {g} must be within 4..65536"));
            }
        }
        self.memory()
            .check(&format!("a {}x{} {} PSF", self.size, self.size, self.method.name()))?;
        if self.method == Method::Huygens && self.integrate {
            // (It evaluates the field at pixel centres only; said rather than ignored.)
            return arg("integrate: the Huygens PSF samples pixel centres and does not integrate over pixels; use method fft, or a finer pixel and sum blocks");
        }
        Ok(())
    }
}

/// Named numbers and strings describing how a PSF was computed, plus warnings.
#[derive(Clone, Debug, Default)]
pub struct Diagnostics {
    pub values: Map<String, Value>,
    pub warnings: Vec<String>,
}

impl Diagnostics {
    pub fn set(&mut self, key: &str, v: impl Into<Value>) {
        self.values.insert(key.to_string(), v.into());
    }
    pub fn warn(&mut self, msg: String) {
        self.warnings.push(msg);
    }
    pub fn to_json(&self) -> Value {
        let mut m = self.values.clone();
        m.insert("warnings".into(), Value::from(self.warnings.clone()));
        Value::Object(m)
    }
}

pub struct Psf {
    pub size: usize,
    pub data: Vec<f64>,
    /// Strehl ratio; None where it cannot be trusted (the diagnostics then hold
    /// `"strehl": null` and a warning saying why).
    pub strehl: Option<f64>,
    pub diagnostics: Diagnostics,
}

/// Largest Strehl ratio accepted (1 plus rounding and peak-refinement slack).
const STREHL_MAX: f64 = 1.0 + 1e-3;

/// Sum in eight interleaved lanes (vectorizes; the same order, so the same bits, every run).
pub(crate) fn sum_lanes(v: &[f64]) -> f64 {
    let mut acc = [0.0; 8];
    let mut chunks = v.chunks_exact(8);
    for c in &mut chunks {
        for (a, x) in acc.iter_mut().zip(c) {
            *a += x;
        }
    }
    for (a, x) in acc.iter_mut().zip(chunks.remainder()) {
        *a += x;
    }
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

/// k! as a float (the Taylor coefficients of the FFT and Huygens expansions).
pub(crate) fn factorial(k: usize) -> f64 {
    (1..=k).map(|i| i as f64).product()
}

/// Sub-sample offset of a peak from three samples (parabola vertex), within +-0.5.
pub(crate) fn parabolic_offset(l: f64, c: f64, r: f64) -> f64 {
    let den = l - 2.0 * c + r;
    if den < 0.0 {
        (0.5 * (l - r) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Window energy above the transmitted flux by more than this fraction is a failed PSF.
pub const ENERGY_EXCESS_TOL: f64 = 1e-2;

/// Monochromatic PSF at `field_deg`, `wavelength_nm`.
pub fn psf(lens: &Lens, field_deg: f64, wavelength_nm: f64, o: &PsfOptions) -> Result<Psf> {
    psf_path(lens, field_deg, wavelength_nm, o).map(|r| r.0)
}

/// The PSF, and whether the fast path (psf/fast.rs) computed it: then every ray of its
/// pupil set reached the image (no vignetting).
pub(crate) fn psf_path(lens: &Lens, field_deg: f64, wavelength_nm: f64, o: &PsfOptions) -> Result<(Psf, bool)> {
    o.check()?;
    if lens.image_curvature != 0.0 {
        let flat = crate::image::flat_at_field(lens, field_deg, o.aiming)?;
        return psf_path(&flat, field_deg, wavelength_nm, o);
    }
    if o.method == Method::Auto {
        let t0 = Instant::now();
        let pr = auto::probe(lens, field_deg, wavelength_nm, o.aiming, o.size as f64 * o.pixel_mm)?;
        let cands = auto::candidates(&pr, o, lens.surfaces.len());
        let (c, _) = auto::choose(&cands, o.accuracy);
        let probe_s = t0.elapsed().as_secs_f64();
        // A PSF that fails its own checks (a window holding more than the transmitted
        // energy) escalates to the next candidate predicted at least as accurate, in cost order.
        let mut failed: Vec<String> = vec![];
        let mut flags: Vec<String> = vec![];
        // The PSF of candidate `c` as auto's answer: its choice, flags and escalations recorded.
        let answer = |mut p: Psf, c: &auto::Candidate, flags: &mut Vec<String>, failed: &[String]| -> Psf {
            // Predicted to meet the target: the candidate used, after any escalation.
            let met = c.predicted_error <= o.accuracy;
            auto::record(&mut p.diagnostics, c, met, &pr, o.accuracy, probe_s);
            if let Some(why) = auto::flagged(&p.diagnostics, c) {
                // Flagged, and no candidate left to escalate to: said, not hidden.
                p.diagnostics.warn(format!(
                    "auto: {} is flagged by its own checks ({why}) and no candidate predicted as accurate is left; its error may exceed the target",
                    c.name()
                ));
                flags.push(format!("{}: {why}", c.name()));
            }
            if !flags.is_empty() {
                p.diagnostics.set("auto_flagged", flags.clone());
            }
            if !failed.is_empty() {
                p.diagnostics.set("auto_escalated_from", failed.to_vec());
                p.diagnostics.warn(format!(
                    "auto: {} failed its checks; escalated to {}",
                    failed.join(", "),
                    c.name()
                ));
            }
            p.diagnostics.set("time_s", t0.elapsed().as_secs_f64());
            p
        };
        // Every fast candidate given up at once where the fast path fell back for its pupil
        // (fits, traced area, rays of the coarse set), which no sampling changes.
        let rule_out_fast = |failed: &mut Vec<String>| {
            for k in cands.iter().filter(|k| k.fast) {
                let name = k.name();
                if !failed.contains(&name) {
                    failed.push(name);
                }
            }
        };
        let mut next = Some(c);
        while let Some(c) = next.take() {
            let chosen = PsfOptions {
                method: c.method,
                fast: c.fast,
                pupil_samples: c.pupil_samples,
                ..o.clone()
            };
            match psf_path(lens, field_deg, wavelength_nm, &chosen) {
                // A result its own checks flag (auto::flagged: the fast path fell back, the
                // FFT's field or Taylor expansion failed, the pupil far undersampled) is not
                // what the model predicted: the next candidate, where there is one.
                Ok((p, clear)) if auto::flagged(&p.diagnostics, &c).is_some() => {
                    let mut tried = failed.clone();
                    tried.push(c.name());
                    let pupil_fell_back = c.fast
                        && p.diagnostics
                            .values
                            .get("fast_fallback")
                            .and_then(Value::as_str)
                            .is_some_and(fast::fallback_is_the_pupils);
                    if pupil_fell_back {
                        rule_out_fast(&mut tried);
                    }
                    match auto::escalate(&cands, &c, &tried) {
                        Some(k) => {
                            let why = auto::flagged(&p.diagnostics, &c).unwrap_or_default();
                            flags.push(format!("{}: {why}", c.name()));
                            failed = tried;
                            next = Some(k);
                        }
                        // Nothing left to escalate to: this PSF, with its flag said.
                        None => return Ok((answer(p, &c, &mut flags, &failed), clear)),
                    }
                }
                Ok((p, clear)) => return Ok((answer(p, &c, &mut flags, &failed), clear)),
                // A PSF its own checks refuse, or one this machine cannot hold (a candidate's
                // memory need above what is available): the next candidate.
                Err(EngineError::Psf(why)) | Err(EngineError::Argument(why)) => {
                    failed.push(c.name());
                    if c.fast
                        && why
                            .split_once(fast::FELL_BACK)
                            .is_some_and(|(_, r)| fast::fallback_is_the_pupils(r))
                    {
                        rule_out_fast(&mut failed);
                    }
                    next = auto::escalate(&cands, &c, &failed);
                    if next.is_none() {
                        return Err(EngineError::Psf(format!(
                            "auto: every candidate failed ({}); last: {why}",
                            failed.join(", ")
                        )));
                    }
                }
                Err(e) => return Err(e),
            }
        }
        unreachable!("the loop returns");
    }
    if fast::applies(o) {
        // Single threaded (the batch runs many of these side by side).
        let t0 = Instant::now();
        let sys = System::new(lens, wavelength_nm)?;
        let mut d = Diagnostics::default();
        common_diagnostics(&mut d, o, field_deg, wavelength_nm);
        match fast::fast_psf(&sys, field_deg, o, &mut d)? {
            Ok(data) => return finish(d, data, None, 1.0, o, field_deg, wavelength_nm, t0).map(|p| (p, true)),
            Err(why) => {
                // The general FFT takes over, at most at FALLBACK_SAMPLES: the fast path's N
                // counts direction cells across the pupil (up to 1024), which as the general
                // FFT's pupil samples would be grids of 4N points.
                let general = PsfOptions {
                    pupil_samples: o.pupil_samples.min(fast::FALLBACK_SAMPLES),
                    ..o.clone()
                };
                let mut p = match rayon::scope(|_| psf_in_pool(lens, field_deg, wavelength_nm, &general)) {
                    Ok(p) => p,
                    Err(EngineError::Psf(m)) => return Err(EngineError::Psf(format!("{m}; {}{why}", fast::FELL_BACK))),
                    Err(e) => return Err(e),
                };
                p.diagnostics.set("fft_mode", "general");
                p.diagnostics.set("fast_fallback", why);
                return Ok((p, false));
            }
        }
    }
    // Run on a thread of the pool: the tracing and the transforms each go parallel, and
    // from a thread outside the pool every parallel section would be a round trip to it.
    rayon::scope(|_| psf_in_pool(lens, field_deg, wavelength_nm, o)).map(|p| (p, false))
}

fn common_diagnostics(d: &mut Diagnostics, o: &PsfOptions, field_deg: f64, wavelength_nm: f64) {
    d.set("method", o.method.name());
    d.set("field_deg", field_deg);
    d.set("wavelength_nm", wavelength_nm);
    d.set("pupil_samples", o.pupil_samples as f64);
    d.set("pixel_um", o.pixel_mm * 1e3);
    d.set("size", o.size as f64);
    d.set(
        "sampling",
        if o.integrate || o.method == Method::Geometric {
            "integrate"
        } else {
            "point"
        },
    );
    d.set("aiming", if o.aiming == Aiming::Real { "real" } else { "paraxial" });
}

/// Checks shared by every method: energy outside the window, non-finite values; the
/// Strehl ratio and the time recorded.
#[allow(clippy::too_many_arguments)]
fn finish(
    mut d: Diagnostics,
    data: Vec<f64>,
    strehl: Option<f64>,
    transmitted: f64,
    o: &PsfOptions,
    field_deg: f64,
    wavelength_nm: f64,
    t0: Instant,
) -> Result<Psf> {
    let e = d.values.get("energy_in_window").and_then(Value::as_f64).unwrap_or(1.0);
    // More energy in the window than was transmitted: the sampled field is wrong (aliasing,
    // pupil distortion the method cannot follow). No such PSF leaves the engine.
    if !(e <= 1.0 + ENERGY_EXCESS_TOL) {
        return Err(EngineError::Psf(format!(
            "{} PSF at {field_deg} deg, {wavelength_nm} nm is wrong: the {}x{} window holds {e:.3} times the transmitted energy (aliasing, pupil distortion, or point samples coarser than the PSF's detail); use more pupil samples, method huygens, finer pixels or integrate{}",
            crate::psf::auto::label(o.method.name(), d.values.get("fft_mode").and_then(Value::as_str) == Some("direction_grid"), o.pupil_samples),
            o.size,
            o.size,
            if d.warnings.is_empty() { String::new() } else { format!(" (warnings: {})", d.warnings.join("; ")) }
        )));
    }
    if e < 0.99 && transmitted > 0.0 {
        d.warn(format!(
            "{:.1}% of the transmitted energy falls outside the {}x{} window",
            100.0 * (1.0 - e),
            o.size,
            o.size
        ));
    }
    // (Blocks without an early exit inside, so that the test vectorizes.)
    if data
        .chunks(16)
        .any(|c| c.iter().fold(false, |bad, v| bad | !v.is_finite()))
    {
        return Err(EngineError::Psf(format!(
            "non-finite PSF value at {field_deg} deg, {wavelength_nm} nm"
        )));
    }
    d.set("strehl", strehl.map_or(Value::Null, Value::from));
    d.set("time_s", t0.elapsed().as_secs_f64());
    Ok(Psf {
        size: o.size,
        data,
        strehl,
        diagnostics: d,
    })
}

fn psf_in_pool(lens: &Lens, field_deg: f64, wavelength_nm: f64, o: &PsfOptions) -> Result<Psf> {
    let t0 = Instant::now();
    let sys = System::new(lens, wavelength_nm)?;
    let mut d = Diagnostics::default();
    let p = pupil::sample_pupil(&sys, field_deg, o.aiming, o.pupil_samples)?;
    let transmitted = p.transmitted_fraction();
    let step = p.max_phase_step();
    common_diagnostics(&mut d, o, field_deg, wavelength_nm);
    d.set("chief_x_mm", p.chief.x);
    d.set("chief_y_mm", p.chief.y);
    d.set("transmitted_fraction", transmitted);
    d.set("max_phase_step_waves", step);
    d.set("reference_sphere_radius_mm", p.radius);
    let [_, missed, clipped, tir, invalid] = p.status_counts;
    d.set("rays_missed", missed as f64);
    d.set("rays_clipped", clipped as f64);
    d.set("rays_tir", tir as f64);
    if missed + tir + invalid > 0 {
        d.warn(format!(
            "partial pupil: {missed} rays missed a surface and {tir} were totally internally reflected (of {} launched); the PSF uses the {} that arrived",
            p.inside.iter().filter(|v| **v).count(),
            p.n_valid()
        ));
    }
    if o.method != Method::Geometric && step > 0.5 {
        d.warn(format!(
            "pupil undersampled: the wavefront changes by {step:.2} waves between neighbouring samples (> 0.5); the PSF aliases: increase pupil_samples"
        ));
    }
    pupil::check_samples_across(&p, &mut d);
    let (data, strehl) = match o.method {
        Method::Geometric => {
            let (data, s) = geometric::geometric_psf(&p, o, &mut d);
            (data, Some(s))
        }
        Method::Fft => fft::fft_psf(&p, o, &mut d)?,
        Method::Huygens => {
            let (data, s) = huygens::huygens_psf(&p, o, &mut d)?;
            (data, Some(s))
        }
        Method::Auto => unreachable!("method auto is resolved in psf_path"),
    };
    // A Strehl ratio above 1 (or not finite) means the sampled field is wrong: no number.
    let strehl = match strehl {
        Some(s) if !(s.is_finite() && s <= STREHL_MAX) => {
            d.warn(format!(
                "Strehl not reported: the computed value {s:.3e} exceeds 1, so the sampled field is wrong (undersampled pupil or aliasing; see the other warnings)"
            ));
            None
        }
        // The Strehl's direct pupil sum needs the same sampling as the PSF itself.
        Some(_) if o.method != Method::Geometric && step > 0.5 => {
            d.warn(format!(
                "Strehl not reported: the pupil is undersampled ({step:.2} waves between neighbouring samples > 0.5)"
            ));
            None
        }
        s => s,
    };
    pupil::recycle(p);
    finish(d, data, strehl, transmitted, o, field_deg, wavelength_nm, t0)
}
