//! The one-pass gradient of a design's PSF set: dL/d(lens parameters) from dL/d(PSFs) and
//! dL/d(relative illumination), for the set rgb.rs computes (fields x channels, each
//! channel's wavelengths weighted and normalized to unit sum, binned to sensor pixels where
//! asked), with the image plane at the best focus where asked (the dataset's refocusing).
//!
//! Each PSF by the fast FFT's reverse pass (psf/fast_adjoint.rs); the channel's
//! normalization p / sum(p) and the sensor binning by their transposes; the relative
//! illumination and the best focus by forward-mode tangents (tangent.rs). The focus enters as
//! one more direction, the image plane's: dL/dtheta += dL/dz dz_best/dtheta.
//!
//! Where a PSF of the set is not computed by the fast path with fitted pupils (`auto` chose
//! another method, the fits missed their tolerance, the path fell back), there is no one-pass
//! gradient for the design: `SetGradient::fallback` says which PSF and why, and the caller
//! differentiates that design by differences.

use crate::aim::Aiming;
use crate::error::{arg, Result};
use crate::lens::Lens;
use crate::psf::fast_adjoint::linearize;
use crate::psf::{auto, fast, sum_lanes, Diagnostics, Method, PsfOptions, ENERGY_EXCESS_TOL};
use crate::rgb::{check_channels, Channels, SensorBinning};
use crate::tangent::{best_focus_tangents, irradiance_tangents, perturbed, Dual, Param};
use crate::trace::System;
use rayon::prelude::*;

/// The image plane at the best focus (focus.rs) over these fields, (wavelength nm, weight)
/// pairs and polar-grid rings.
#[derive(Clone, Debug)]
pub struct FocusRule {
    pub fields: Vec<f64>,
    pub wavelengths: Vec<(f64, f64)>,
    pub rings: usize,
}

/// What `psf_set_vjp` returns.
#[derive(Clone, Debug)]
pub struct SetGradient {
    /// dL/d(each parameter); empty where `fallback` says why there is none.
    pub grad: Vec<f64>,
    /// The set's PSFs (fields x channels x size x size, unit sum per channel, before any
    /// sensor binning) and relative illumination (fields x channels), as psf_batch has them.
    pub psf: Vec<f64>,
    pub relative_illumination: Vec<f64>,
    /// The first PSF without a one-pass gradient, and why.
    pub fallback: Option<String>,
}

/// The most parameters one call takes (the image plane's direction counted).
pub const MAX_DIRECTIONS: usize = 48;

/// The gradient of L along `params` at `lens` (already refocused where `focus` is given):
/// `g_psf` = dL/dPSF, fields x channels x m x m (m the sensor binning's size, or o.size),
/// `g_ri` = dL/d(relative illumination), fields x channels.
pub fn psf_set_vjp(
    lens: &Lens,
    fields: &[f64],
    channels: &Channels,
    o: &PsfOptions,
    sensor: Option<&SensorBinning>,
    params: &[Param],
    focus: Option<&FocusRule>,
    g_psf: &[f64],
    g_ri: &[f64],
) -> Result<SetGradient> {
    check_channels(channels)?;
    o.check()?;
    let (nf, nc) = (fields.len(), channels.len());
    let m = sensor.map_or(o.size, |b| b.size());
    if let Some(b) = sensor {
        if b.fine() != o.size {
            return arg(format!(
                "psf_set_vjp: sensor binning made for {}x{} PSFs, not {}x{}",
                b.fine(),
                b.fine(),
                o.size,
                o.size
            ));
        }
    }
    if g_psf.len() != nf * nc * m * m || g_ri.len() != nf * nc {
        return arg(format!(
            "psf_set_vjp: dL/dPSF holds {} values and dL/dRI {}, expected {nf} x {nc} x {m} x {m} and {nf} x {nc}",
            g_psf.len(),
            g_ri.len()
        ));
    }
    if let Some(i) = g_psf.iter().chain(g_ri).position(|v| !v.is_finite()) {
        return arg(format!("psf_set_vjp: dL/dPSF or dL/dRI value {i} is not finite"));
    }
    for p in params {
        if perturbed(lens, *p, 0.0).is_none() {
            return arg(format!(
                "psf_set_vjp: parameter {p:?} names nothing in this lens (its surfaces, or its aperture's kind)"
            ));
        }
    }
    // The image plane as one more direction where the focus follows the lens.
    let mut all = params.to_vec();
    let image = Param::Thickness(lens.surfaces.len() - 1);
    let image_k = focus.map(|_| {
        all.iter().position(|p| *p == image).unwrap_or_else(|| {
            all.push(image);
            all.len() - 1
        })
    });
    let mut r = match all.len() {
        0..=8 => set_vjp::<8>(lens, fields, channels, o, sensor, &all, focus, image_k, g_psf, g_ri)?,
        9..=24 => set_vjp::<24>(lens, fields, channels, o, sensor, &all, focus, image_k, g_psf, g_ri)?,
        25..=MAX_DIRECTIONS => {
            set_vjp::<MAX_DIRECTIONS>(lens, fields, channels, o, sensor, &all, focus, image_k, g_psf, g_ri)?
        }
        n => {
            return arg(format!(
                "psf_set_vjp: {n} directions (parameters and the image plane), at most {MAX_DIRECTIONS}"
            ))
        }
    };
    if r.fallback.is_none() {
        r.grad.truncate(params.len());
    }
    Ok(r)
}

/// One PSF of the set: its field, channel, wavelength and weight in the channel.
struct Visit {
    field: usize,
    channel: usize,
    wl: f64,
    weight: f64,
}

/// A PSF's part: its gradient, its normalized PSF times its channel weight, its relative
/// illumination times that weight; or why it has no one-pass gradient.
type Part<const N: usize> = std::result::Result<([f64; N], Vec<f64>, f64), String>;

fn set_vjp<const N: usize>(
    lens: &Lens,
    fields: &[f64],
    channels: &Channels,
    o: &PsfOptions,
    sensor: Option<&SensorBinning>,
    all: &[Param],
    focus: Option<&FocusRule>,
    image_k: Option<usize>,
    g_psf: &[f64],
    g_ri: &[f64],
) -> Result<SetGradient> {
    let (nf, nc, s) = (fields.len(), channels.len(), o.size);
    let none = |why: String| SetGradient {
        grad: vec![],
        psf: vec![],
        relative_illumination: vec![],
        fallback: Some(why),
    };
    if o.aiming != Aiming::Paraxial {
        return Ok(none("real-ray aiming: the tangents follow paraxial aiming only".into()));
    }
    if lens.image_curvature != 0.0 {
        return Ok(none("a curved image surface".into()));
    }
    // dL/d(each channel's unit-sum PSF) at the PSF's own pixels.
    let m = sensor.map_or(s, |b| b.size());
    let g_fine: Vec<Vec<f64>> = g_psf
        .chunks_exact(m * m)
        .map(|g| match sensor {
            Some(b) => {
                let mut out = vec![0.0; s * s];
                b.apply_adjoint(g, &mut out);
                out
            }
            None => g.to_vec(),
        })
        .collect();
    let visits: Vec<Visit> = (0..nf)
        .flat_map(|field| {
            channels.iter().enumerate().flat_map(move |(channel, list)| {
                let wsum: f64 = list.iter().map(|p| p.1).sum();
                list.iter().map(move |&(wl, w)| Visit {
                    field,
                    channel,
                    wl,
                    weight: w / wsum,
                })
            })
        })
        .collect();
    // Each wavelength's on-axis irradiance with its tangents, shared by its fields.
    let mut wls: Vec<f64> = visits.iter().map(|v| v.wl).collect();
    wls.sort_by(f64::total_cmp);
    wls.dedup();
    let axis: Vec<Dual<N>> = wls
        .par_iter()
        .map(|&wl| irradiance_tangents::<N>(lens, all, 0.0, wl))
        .collect::<Result<_>>()?;
    let parts: Vec<Result<Part<N>>> = visits
        .par_iter()
        .map(|v| {
            let k = v.field * nc + v.channel;
            let e0 = axis[wls.partition_point(|&w| w < v.wl)];
            psf_part::<N>(lens, fields[v.field], v, o, all, &g_fine[k], g_ri[k], e0)
        })
        .collect();
    // In a fixed order: the same sums on any number of threads.
    let mut grad = [0.0; N];
    let mut psf = vec![0.0; nf * nc * s * s];
    let mut ri = vec![0.0; nf * nc];
    for (v, part) in visits.iter().zip(parts) {
        let (g, p, r) = match part? {
            Ok(x) => x,
            Err(why) => return Ok(none(format!("field {} deg, {} nm: {why}", fields[v.field], v.wl))),
        };
        let k = v.field * nc + v.channel;
        grad.iter_mut().zip(g).for_each(|(a, b)| *a += b);
        psf[k * s * s..(k + 1) * s * s]
            .iter_mut()
            .zip(&p)
            .for_each(|(a, b)| *a += b);
        ri[k] += r;
    }
    if let (Some(rule), Some(ik)) = (focus, image_k) {
        // z = z_best(theta): dL/dtheta_j += dL/dz dz/dtheta_j (the image plane's own tangent
        // is -1 there: the best plane does not move with it).
        let dz = best_focus_tangents::<N>(lens, all, &rule.fields, &rule.wavelengths, rule.rings)?;
        let gz = grad[ik];
        for (a, t) in grad.iter_mut().zip(dz.d) {
            *a += gz * t;
        }
    }
    Ok(SetGradient {
        grad: grad[..all.len()].to_vec(),
        psf,
        relative_illumination: ri,
        fallback: None,
    })
}

/// One PSF's part of the set's gradient (see `Part`), with its channel's dL/d(unit-sum PSF)
/// and dL/d(relative illumination).
fn psf_part<const N: usize>(
    lens: &Lens,
    field: f64,
    v: &Visit,
    o: &PsfOptions,
    all: &[Param],
    g_fine: &[f64],
    g_ri: f64,
    axis: Dual<N>,
) -> Result<Part<N>> {
    // What psf_path computes this PSF with: auto's first candidate, or the options as given.
    let (opts, cand) = if o.method == Method::Auto {
        let pr = auto::probe(lens, field, v.wl, o.aiming, o.size as f64 * o.pixel_mm)?;
        let cands = auto::candidates(&pr, o, lens.surfaces.len());
        let (c, _) = auto::choose(&cands, o.accuracy);
        let chosen = PsfOptions {
            method: c.method,
            fast: c.fast,
            pupil_samples: c.pupil_samples,
            ..o.clone()
        };
        (chosen, Some(c))
    } else {
        (o.clone(), None)
    };
    if !fast::applies(&opts) {
        return Ok(Err(format!(
            "computed by {} (not the fast FFT): no one-pass gradient",
            cand.map_or(o.method.name().to_string(), |c| c.name())
        )));
    }
    let sys = System::new(lens, v.wl)?;
    let mut d = Diagnostics::default();
    let lin = match linearize::<N>(&sys, field, &opts, all, &mut d)? {
        Ok(l) => l,
        Err(why) => return Ok(Err(why.to_string())),
    };
    if let Some(why) = cand.as_ref().and_then(|c| auto::flagged(&d, c)) {
        return Ok(Err(format!("auto would not keep this PSF ({why})")));
    }
    let e = d.values.get("energy_in_window").and_then(|x| x.as_f64()).unwrap_or(1.0);
    if !(e <= 1.0 + ENERGY_EXCESS_TOL) || lin.psf.iter().any(|x| !x.is_finite()) {
        return Ok(Err("the PSF fails its own checks (the engine refuses it)".into()));
    }
    let tot = sum_lanes(&lin.psf);
    if !(tot > 0.0) {
        return Ok(Err("no energy reaches the PSF window".into()));
    }
    // q = weight p / sum(p): dL/dp = weight (g - <g, q'>) / sum(p), q' = p / sum(p).
    let gq: f64 = g_fine.iter().zip(&lin.psf).map(|(a, b)| a * b).sum::<f64>() / tot;
    let gp: Vec<f64> = g_fine.iter().map(|x| v.weight * (x - gq) / tot).collect();
    let mut grad = lin.vjp(&gp)?;
    // the relative illumination: the field's irradiance over the axis's (tangent.rs)
    let ri = if field == 0.0 {
        Dual::constant(1.0)
    } else {
        irradiance_tangents::<N>(lens, all, field, v.wl)? / axis
    };
    grad.iter_mut().zip(ri.d).for_each(|(a, t)| *a += g_ri * v.weight * t);
    let p = lin.psf.iter().map(|x| v.weight * x / tot).collect();
    Ok(Ok((grad, p, v.weight * ri.v)))
}
