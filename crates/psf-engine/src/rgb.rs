//! RGB PSFs: each colour channel integrates several wavelengths with weights (a sensor's
//! spectral response), normalized to unit sum, with its relative illumination; and the
//! batch over designs x fields x channels that the dataset generator runs.

use crate::error::{arg, Result};
use crate::lens::Lens;
use crate::psf::{psf, Diagnostics, PsfOptions};
use crate::spot::relative_illumination;
use rayon::prelude::*;

/// Rings of the polar grid used for relative illumination.
const RI_RINGS: usize = 24;

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
        if list.is_empty() || list.iter().any(|(wl, w)| !(*wl > 0.0 && wl.is_finite() && *w >= 0.0 && w.is_finite())) || list.iter().map(|p| p.1).sum::<f64>() <= 0.0 {
            return arg(format!("channel {c}: needs (wavelength_nm > 0, weight >= 0) pairs with a positive total weight"));
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
    for (c, list) in channels.iter().enumerate() {
        let out = &mut data[c * s * s..(c + 1) * s * s];
        let wsum: f64 = list.iter().map(|p| p.1).sum();
        for &(wl, w) in list {
            let p = psf(lens, field_deg, wl, o)?;
            let tot: f64 = p.data.iter().sum();
            if tot > 0.0 {
                out.iter_mut().zip(&p.data).for_each(|(o, v)| *o += w / wsum * v / tot);
            }
            ri[c] += w / wsum * relative_illumination(lens, field_deg, wl, RI_RINGS, o.aiming)?;
            diags.push(p.diagnostics);
        }
    }
    Ok(RgbPsf { size: s, data, relative_illumination: ri, diagnostics: diags })
}

pub struct Batch {
    /// designs x fields x channels x size x size.
    pub psf: Vec<f32>,
    pub relative_illumination: Vec<f64>,
    pub errors: Vec<Option<String>>,
}

/// Every (design, field) pair in parallel; a design that fails records its first error and
/// keeps zeros.
pub fn psf_batch(lenses: &[Lens], fields: &[f64], channels: &Channels, o: &PsfOptions) -> Result<Batch> {
    check_channels(channels)?;
    o.check()?;
    let (nf, nc, s) = (fields.len(), channels.len(), o.size);
    let per = nc * s * s;
    let results: Vec<Result<RgbPsf>> = (0..lenses.len() * nf).into_par_iter().map(|i| psf_rgb(&lenses[i / nf], fields[i % nf], channels, o)).collect();
    let mut psfv = vec![0.0f32; lenses.len() * nf * per];
    let mut ri = vec![0.0; lenses.len() * nf * nc];
    let mut errors: Vec<Option<String>> = vec![None; lenses.len()];
    for (i, r) in results.into_iter().enumerate() {
        let d = i / nf;
        match r {
            Ok(p) => {
                psfv[i * per..(i + 1) * per].iter_mut().zip(&p.data).for_each(|(o, v)| *o = *v as f32);
                ri[i * nc..(i + 1) * nc].copy_from_slice(&p.relative_illumination);
            }
            Err(e) => {
                if errors[d].is_none() {
                    errors[d] = Some(format!("field {} deg: {e}", fields[i % nf]));
                }
            }
        }
    }
    for (d, e) in errors.iter().enumerate() {
        if e.is_some() {
            psfv[d * nf * per..(d + 1) * nf * per].iter_mut().for_each(|v| *v = 0.0);
            ri[d * nf * nc..(d + 1) * nf * nc].iter_mut().for_each(|v| *v = 0.0);
        }
    }
    Ok(Batch { psf: psfv, relative_illumination: ri, errors })
}
