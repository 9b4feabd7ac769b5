//! RGB PSFs: each colour channel integrates several wavelengths with weights (a sensor's
//! spectral response), normalized to unit sum, with its relative illumination; and the
//! batch over designs x fields x channels that the dataset generator runs.

use crate::error::{arg, Result};
use crate::lens::Lens;
use crate::psf::{fast, psf_path, Diagnostics, PsfOptions};
use crate::spot::{field_fold, irradiance_adaptive, relative_illumination_from};
use rayon::prelude::*;

pub struct RgbPsf {
    pub size: usize,
    /// channels x size x size, each channel summing to 1.
    pub data: Vec<f64>,
    pub relative_illumination: Vec<f64>,
    pub diagnostics: Vec<Diagnostics>,
}

pub type Channels = Vec<Vec<(f64, f64)>>;

pub fn check_channels(ch: &Channels) -> Result<()> {
    if ch.is_empty() {
        return arg("channels: need at least one channel");
    }
    for (c, list) in ch.iter().enumerate() {
        if list.is_empty()
            || list
                .iter()
                .any(|(wl, w)| !(*wl > 0.0 && wl.is_finite() && *w >= 0.0 && w.is_finite()))
            || list.iter().map(|p| p.1).sum::<f64>() <= 0.0
        {
            return arg(format!(
                "channel {c}: needs (wavelength_nm > 0, weight >= 0) pairs with a positive total weight"
            ));
        }
    }
    Ok(())
}

pub fn psf_rgb(lens: &Lens, field_deg: f64, channels: &Channels, o: &PsfOptions) -> Result<RgbPsf> {
    check_channels(channels)?;
    let s = o.size;
    let mut data = vec![0.0; channels.len() * s * s];
    let mut ri = vec![0.0; channels.len()];
    let mut diags = vec![];
    rgb_core(
        lens,
        field_deg,
        channels,
        o,
        None,
        0.0,
        &mut ri,
        |c, v, k| {
            data[c * s * s..(c + 1) * s * s]
                .iter_mut()
                .zip(v)
                .for_each(|(o, v)| *o = v * k)
        },
        |d| diags.push(d),
    )?;
    Ok(RgbPsf {
        size: s,
        data,
        relative_illumination: ri,
        diagnostics: diags,
    })
}

/// An error where the image of the lens's field folds between the axis and `reach_deg`
/// (`spot::field_fold`): its relative illumination cannot be computed per field (nor is any
/// negative or non-finite one returned).
fn check_no_fold(lens: &Lens, reach_deg: f64, aiming: crate::aim::Aiming) -> Result<()> {
    match field_fold(lens, reach_deg, lens.primary_nm, aiming)? {
        None => Ok(()),
        Some(f) => Err(crate::error::EngineError::Trace(format!(
            "the image of the field folds: at pupil point ({:.2}, {:.2}) the image height falls by {:.4} mm \
             from {:.3} to {:.3} deg ({} nm), so rays of different fields cross and the relative \
             illumination (and the field's PSF) cannot be computed per field",
            f.px,
            f.py,
            -f.step_mm,
            f.field_deg - reach_deg / crate::spot::FOLD_FIELDS as f64,
            f.field_deg,
            lens.primary_nm
        ))),
    }
}

/// The channels of one field: `sink(c, psf, k)` receives channel c's PSF as `psf` times
/// `k` (unit sum), `ri` its relative illumination; `diag` each wavelength's
/// diagnostics. `axis[k]`: the on-axis irradiance of the k-th wavelength (channels
/// flattened), where the caller has it. A design whose image of the field folds
/// (`check_no_fold` over its fields and this one) is an error; `fold_checked_deg`: the
/// reach the caller has already checked (the batch checks each design once), else 0.
#[allow(clippy::too_many_arguments)]
fn rgb_core(
    lens: &Lens,
    field_deg: f64,
    channels: &Channels,
    o: &PsfOptions,
    axis: Option<&[Option<f64>]>,
    fold_checked_deg: f64,
    ri: &mut [f64],
    mut sink: impl FnMut(usize, &[f64], f64),
    mut diag: impl FnMut(Diagnostics),
) -> Result<()> {
    let s = o.size;
    let reach = lens.max_field_deg().max(field_deg.abs());
    if !(reach <= fold_checked_deg) {
        check_no_fold(lens, reach, o.aiming)?;
    }
    let mut acc = vec![];
    let mut k = 0;
    for (c, list) in channels.iter().enumerate() {
        let wsum: f64 = list.iter().map(|p| p.1).sum();
        if list.len() > 1 {
            acc.clear();
            acc.resize(s * s, 0.0);
        }
        for &(wl, w) in list {
            let (mut p, _) = psf_path(lens, field_deg, wl, o)?;
            let tot = crate::psf::sum_lanes(&p.data);
            // Every channel sums to 1: a wavelength whose PSF holds no energy cannot be
            // normalized (nor silently left out of its channel's weights).
            if !(tot > 0.0) {
                return Err(crate::error::EngineError::Psf(format!(
                    "no energy reaches the PSF window at {field_deg} deg, {wl} nm (channel {c})"
                )));
            }
            if list.len() == 1 {
                // A single wavelength: the PSF times 1 / its sum.
                sink(c, &p.data, 1.0 / tot);
                fast::give_f64(std::mem::take(&mut p.data));
            } else {
                acc.iter_mut().zip(&p.data).for_each(|(o, v)| *o += w / wsum * v / tot);
            }
            ri[c] += w / wsum * relative_illumination_from(lens, field_deg, wl, o.aiming, axis.and_then(|a| a[k]))?;
            k += 1;
            diag(p.diagnostics);
        }
        if list.len() > 1 {
            sink(c, &acc, 1.0);
        }
        if !(ri[c] >= 0.0 && ri[c].is_finite()) {
            return Err(crate::error::EngineError::Trace(format!(
                "relative illumination {:.4} in channel {c} at {field_deg} deg is not a finite value >= 0: the design is broken",
                ri[c]
            )));
        }
    }
    Ok(())
}

/// Integration of a super-resolved PSF over sensor pixels: each fine pixel is a box of one
/// pitch around its centre, each sensor pixel one of its pitch; both grids are centred on
/// pixel `size / 2` (the chief ray's). A sensor pixel sums the fine pixels it overlaps,
/// each weighted by the fraction of its area inside (separable in x and y).
pub struct SensorBinning {
    fine: usize,
    size: usize,
    /// Per sensor pixel (either axis): the first fine pixel it overlaps and the weights.
    taps: Vec<(usize, Vec<f64>)>,
}

impl SensorBinning {
    pub fn new(fine: usize, pitch_mm: f64, size: usize, sensor_pitch_mm: f64) -> Result<SensorBinning> {
        if !(1..=8192).contains(&size) {
            return arg(format!(
                "sensor binning: {size} sensor pixels across must be within 1..8192"
            ));
        }
        if !(pitch_mm > 0.0 && sensor_pitch_mm > 0.0 && pitch_mm.is_finite() && sensor_pitch_mm.is_finite())
            || fine == 0
            || size == 0
        {
            return arg(format!("sensor binning: need positive pitches and sizes (fine {fine} x {pitch_mm} mm, sensor {size} x {sensor_pitch_mm} mm)"));
        }
        let taps = (0..size)
            .map(|j| {
                let c = (j as f64 - (size / 2) as f64) * sensor_pitch_mm;
                let (lo, hi) = (c - sensor_pitch_mm / 2.0, c + sensor_pitch_mm / 2.0);
                let w: Vec<(usize, f64)> = (0..fine)
                    .filter_map(|i| {
                        let x = (i as f64 - (fine / 2) as f64) * pitch_mm;
                        let ov = hi.min(x + pitch_mm / 2.0) - lo.max(x - pitch_mm / 2.0);
                        (ov > 0.0).then_some((i, ov / pitch_mm))
                    })
                    .collect();
                (w.first().map_or(0, |p| p.0), w.iter().map(|p| p.1).collect())
            })
            .collect();
        Ok(SensorBinning { fine, size, taps })
    }

    /// Sensor pixels (size x size) of one fine PSF (fine x fine, row-major) times `k`.
    pub fn apply(&self, psf: &[f64], k: f64, out: &mut [f32]) {
        let (n, m) = (self.fine, self.size);
        // x first: every fine row into sensor columns; then y.
        let mut rows = vec![0.0; n * m];
        for (r, row) in psf.chunks_exact(n).enumerate() {
            for (j, (i0, w)) in self.taps.iter().enumerate() {
                rows[r * m + j] = w.iter().zip(&row[*i0..]).map(|(a, b)| a * b).sum::<f64>();
            }
        }
        for (i, (r0, w)) in self.taps.iter().enumerate() {
            for j in 0..m {
                let v: f64 = w.iter().enumerate().map(|(t, a)| a * rows[(r0 + t) * m + j]).sum();
                out[i * m + j] = (v * k) as f32;
            }
        }
    }

    /// The adjoint of `apply` (k = 1): dL/d(fine PSF) (fine x fine) from dL/d(sensor pixels)
    /// (size x size), into `out`.
    pub fn apply_adjoint(&self, g: &[f64], out: &mut [f64]) {
        let (n, m) = (self.fine, self.size);
        let mut rows = vec![0.0; n * m];
        for (i, (r0, w)) in self.taps.iter().enumerate() {
            for (t, a) in w.iter().enumerate() {
                for j in 0..m {
                    rows[(r0 + t) * m + j] += a * g[i * m + j];
                }
            }
        }
        out[..n * n].fill(0.0);
        for (r, orow) in out.chunks_exact_mut(n).enumerate() {
            for (j, (i0, w)) in self.taps.iter().enumerate() {
                let gj = rows[r * m + j];
                for (o, a) in orow[*i0..].iter_mut().zip(w) {
                    *o += a * gj;
                }
            }
        }
    }

    pub fn size(&self) -> usize {
        self.size
    }

    /// The fine PSF's size it bins.
    pub fn fine(&self) -> usize {
        self.fine
    }
}

pub struct Batch {
    /// designs x fields x channels x size x size.
    pub psf: Vec<f32>,
    pub relative_illumination: Vec<f64>,
    /// designs x fields x channels: the fraction of the transmitted energy inside the
    /// window (the channel's wavelengths weighted as in its PSF).
    pub energy_in_window: Vec<f64>,
    /// Per design: the PSFs' warnings, each prefixed with its field and wavelength.
    pub warnings: Vec<Vec<String>>,
    pub errors: Vec<Option<String>>,
    /// designs x fields x wavelengths (channels flattened): the method and sampling each
    /// PSF was computed with (`method_used`), what `method = auto` chose included.
    pub methods: Vec<String>,
}

/// The method and sampling a PSF was computed with, from its diagnostics (named as
/// `auto::label`).
pub fn method_used(d: &Diagnostics) -> String {
    let v = &d.values;
    let m = v.get("method").and_then(|x| x.as_str()).unwrap_or("?");
    let fast = v.get("fft_mode").and_then(|x| x.as_str()) == Some("direction_grid");
    let n = v.get("pupil_samples").and_then(|x| x.as_f64()).unwrap_or(0.0);
    crate::psf::auto::label(m, fast, n as usize)
}

/// Every (design, field) pair in parallel, each PSF single threaded where the fast path
/// applies; a design that fails records its first error and keeps zeros. The result does
/// not depend on the number of threads (each task writes only its own slice).
pub fn psf_batch(lenses: &[Lens], fields: &[f64], channels: &Channels, o: &PsfOptions) -> Result<Batch> {
    check_channels(channels)?;
    o.check()?;
    let mut psfv = output_buffer(lenses.len() * fields.len() * channels.len() * o.size * o.size);
    let mut b = psf_batch_into(lenses, fields, channels, o, &mut psfv, None)?;
    b.psf = psfv;
    Ok(b)
}

/// What a batch allocates: the per-thread PSF work (`PsfOptions::memory` on each of
/// `threads`), the outputs the engine allocates itself (`own_out`: the PSFs; `sensor`: the
/// sensor PSFs' size, where the engine allocates them) and the per-PSF records.
pub fn batch_memory(
    nd: usize,
    nf: usize,
    nc: usize,
    o: &PsfOptions,
    threads: usize,
    own_out: bool,
    sensor: Option<usize>,
) -> crate::budget::Need {
    let rows = (nd * nf * nc) as f64;
    let mut parts: Vec<(String, f64)> = o
        .memory()
        .0
        .into_iter()
        .map(|(n, b)| (format!("{n} x {threads} threads"), b * threads as f64))
        .collect();
    if own_out {
        parts.push((
            format!("PSFs {nd}x{nf}x{nc}x{s}x{s} float32", s = o.size),
            rows * (o.size * o.size) as f64 * 4.0,
        ));
    }
    if let Some(m) = sensor {
        parts.push((
            format!("sensor PSFs {nd}x{nf}x{nc}x{m}x{m} float32"),
            rows * (m * m) as f64 * 4.0,
        ));
    }
    parts.push(("records".into(), rows * 64.0));
    crate::budget::Need(parts)
}

/// Zeros over the rows (equal slices of `buf`, one per design) of the designs with an error.
pub fn zero_failed<T: Default + Copy>(buf: &mut [T], errors: &[Option<String>]) {
    let per = buf.len() / errors.len().max(1);
    for (row, e) in buf.chunks_mut(per.max(1)).zip(errors) {
        if e.is_some() {
            row.fill(T::default());
        }
    }
}

/// A zeroed PSF output buffer of `len` values (huge-page backed where the system allows).
pub fn output_buffer(len: usize) -> Vec<f32> {
    crate::trace::huge_pages(vec![0.0f32; len])
}

/// [`psf_batch`] writing the PSFs into `out` (designs x fields x channels x size x size,
/// every value overwritten; a failed design's are zeros), e.g. a caller's reused buffer:
/// no fresh memory to fault in and zero. The returned `Batch` has an empty `psf`.
/// `sensor`: also the sensor-pixel version of every PSF (designs x fields x channels x
/// m x m, m = the binning's size), binned from the double-precision PSF.
pub fn psf_batch_into(
    lenses: &[Lens],
    fields: &[f64],
    channels: &Channels,
    o: &PsfOptions,
    out: &mut [f32],
    sensor: Option<(&SensorBinning, &mut [f32])>,
) -> Result<Batch> {
    check_channels(channels)?;
    o.check()?;
    let (nd, nf, nc, s) = (lenses.len(), fields.len(), channels.len(), o.size);
    let per = nc * s * s;
    if out.len() != nd * nf * per {
        return arg(format!(
            "psf_batch: output holds {} values, expected {nd} x {nf} x {nc} x {s} x {s}",
            out.len()
        ));
    }
    let mut no_sensor = vec![0.0f32; nd * nf];
    let (bin, sensor_buf, sper) = match sensor {
        Some((b, buf)) => {
            if b.fine != s {
                return arg(format!(
                    "psf_batch: sensor binning made for {}x{} PSFs, not {s}x{s}",
                    b.fine, b.fine
                ));
            }
            let sper = nc * b.size * b.size;
            if buf.len() != nd * nf * sper {
                return arg(format!(
                    "psf_batch: sensor output holds {} values, expected {nd} x {nf} x {nc} x {m} x {m}",
                    buf.len(),
                    m = b.size
                ));
            }
            (Some(b), buf, sper)
        }
        None => (None, &mut no_sensor[..], 1),
    };
    let psfv = out;
    // Each design's on-axis irradiance per wavelength, shared by its fields (an error here
    // is left for the field's own computation to report).
    let wls: Vec<f64> = channels.iter().flatten().map(|p| p.0).collect();
    let axis: Vec<Vec<Option<f64>>> = lenses
        .par_iter()
        .map(|l| {
            wls.iter()
                .map(|&wl| irradiance_adaptive(l, 0.0, wl, o.aiming).ok().filter(|e| *e > 0.0))
                .collect()
        })
        .collect();
    // Whether each design's image of the field folds, checked once over its own fields
    // (rgb_core checks a field beyond them itself).
    let folds: Vec<(f64, std::result::Result<(), String>)> = lenses
        .par_iter()
        .map(|l| {
            let reach = l.max_field_deg();
            (reach, check_no_fold(l, reach, o.aiming).map_err(|e| e.to_string()))
        })
        .collect();
    let mut ri = vec![0.0; nd * nf * nc];
    let mut energy = vec![0.0; nd * nf * nc];
    // channel and weight of each wavelength, in the order rgb_core visits them
    let visits: Vec<(usize, f64, f64)> = channels
        .iter()
        .enumerate()
        .flat_map(|(c, list)| {
            let wsum: f64 = list.iter().map(|p| p.1).sum();
            list.iter().map(move |&(wl, w)| (c, wl, w / wsum))
        })
        .collect();
    let nw = visits.len();
    let mut methods = vec![String::new(); nd * nf * nw];
    let results: Vec<(Option<String>, Vec<String>)> = psfv
        .par_chunks_mut(per)
        .zip(sensor_buf.par_chunks_mut(sper))
        .zip(ri.par_chunks_mut(nc))
        .zip(energy.par_chunks_mut(nc))
        .zip(methods.par_chunks_mut(nw))
        .enumerate()
        .map(|(i, ((((out, sout), ri), en), used))| {
            let (d, f) = (i / nf, fields[i % nf]);
            let axis = Some(&axis[d][..]);
            let mut warnings = vec![];
            let mut k = 0;
            let sink = |c: usize, v: &[f64], k: f64| {
                out[c * s * s..(c + 1) * s * s]
                    .iter_mut()
                    .zip(v)
                    .for_each(|(o, v)| *o = (v * k) as f32);
                if let Some(b) = bin {
                    let ss = b.size * b.size;
                    b.apply(v, k, &mut sout[c * ss..(c + 1) * ss]);
                }
            };
            let (reach, folded) = &folds[d];
            if let (Err(e), true) = (folded, f.abs() <= *reach) {
                return (Some(format!("field {f} deg: {e}")), warnings);
            }
            let err = rgb_core(&lenses[d], f, channels, o, axis, *reach, ri, sink, |dg| {
                let (c, wl, w) = visits[k];
                used[k] = method_used(&dg);
                k += 1;
                en[c] += w * dg
                    .values
                    .get("energy_in_window")
                    .and_then(|v| v.as_f64())
                    .unwrap_or(0.0);
                warnings.extend(dg.warnings.iter().map(|m| format!("field {f} deg, {wl} nm: {m}")));
            })
            .err()
            .map(|e| format!("field {f} deg: {e}"));
            (err, warnings)
        })
        .collect();
    let mut errors: Vec<Option<String>> = vec![None; nd];
    let mut warnings: Vec<Vec<String>> = vec![vec![]; nd];
    for (i, (e, w)) in results.into_iter().enumerate() {
        warnings[i / nf].extend(w);
        if let (Some(e), None) = (e, &errors[i / nf]) {
            errors[i / nf] = Some(e);
        }
    }
    zero_failed(psfv, &errors);
    zero_failed(sensor_buf, &errors);
    zero_failed(&mut ri, &errors);
    zero_failed(&mut energy, &errors);
    Ok(Batch {
        psf: vec![],
        relative_illumination: ri,
        energy_in_window: energy,
        warnings,
        errors,
        methods,
    })
}
