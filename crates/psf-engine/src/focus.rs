//! Best focus: the image-plane shift that minimizes the mean over fields of the
//! polychromatic centroid RMS spot squared (Zemax's "Quick Focus" on the RMS spot radius).
//!
//! Behind the last surface every ray is a straight line, so at a plane shifted by `dz` a
//! ray lands at x + dz ux/uz.  The weighted RMS^2 about the centroid is then a quadratic
//! a + 2 b dz + c dz^2 per field; the sum over fields has its minimum at dz = -b / c.

use crate::aim::{Aiming, Beam};
use crate::error::{arg, Result};
use crate::lens::Lens;
use crate::spot::polar_grid;
use crate::trace::System;

/// Image-plane shift (mm, positive = away from the lens) minimizing the mean over `fields`
/// of the RMS spot squared; `wavelengths` are (nm, weight) pairs.  Rays that fail are left
/// out; a field with no ray through adds nothing (0 if none passes anywhere).
pub fn best_focus_shift(
    lens: &Lens,
    fields: &[f64],
    wavelengths: &[(f64, f64)],
    rings: usize,
    aiming: Aiming,
) -> Result<f64> {
    if wavelengths.is_empty() || rings == 0 || wavelengths.iter().any(|p| !(p.1 >= 0.0)) {
        return arg("best focus: need >= 1 wavelength with weights >= 0 and rings >= 1");
    }
    let wsum: f64 = wavelengths.iter().map(|p| p.1).sum();
    if !(wsum > 0.0) {
        return arg("best focus: the wavelength weights sum to 0");
    }
    let (px, py) = polar_grid(rings);
    let systems = wavelengths
        .iter()
        .map(|p| System::new(lens, p.0))
        .collect::<Result<Vec<_>>>()?;
    let (mut b, mut c) = (0.0, 0.0);
    let mut pts: Vec<[f64; 5]> = Vec::with_capacity(px.len() * wavelengths.len());
    for &f in fields {
        pts.clear();
        for (sys, &(_, wt)) in systems.iter().zip(wavelengths) {
            let beam = Beam::new(sys, f, aiming)?;
            let (launches, rays) = beam.trace_pupil(&px, &py);
            for (l, r) in launches.iter().zip(&rays) {
                if r.ok() && r.d.z.abs() > 1e-12 {
                    pts.push([
                        r.p.x,
                        r.p.y,
                        r.d.x / r.d.z,
                        r.d.y / r.d.z,
                        wt / wsum * beam.flux_weight(l),
                    ]);
                }
            }
        }
        let sw: f64 = pts.iter().map(|p| p[4]).sum();
        if !(sw > 0.0) {
            continue;
        }
        let mean = |k: usize| pts.iter().map(|p| p[4] * p[k]).sum::<f64>() / sw;
        let m = [mean(0), mean(1), mean(2), mean(3)];
        for p in &pts {
            let w = p[4] / sw;
            let (ax, ay, sx, sy) = (p[0] - m[0], p[1] - m[1], p[2] - m[2], p[3] - m[3]);
            b += w * (ax * sx + ay * sy);
            c += w * (sx * sx + sy * sy);
        }
    }
    Ok(if c > 0.0 { -b / c } else { 0.0 })
}

/// [`best_focus_shift`] for many designs in parallel (one result per design, in order).
pub fn best_focus_each(
    lenses: &[Lens],
    fields: &[f64],
    wavelengths: &[(f64, f64)],
    rings: usize,
    aiming: Aiming,
) -> Vec<Result<f64>> {
    use rayon::prelude::*;
    lenses
        .par_iter()
        .map(|l| best_focus_shift(l, fields, wavelengths, rings, aiming))
        .collect()
}
