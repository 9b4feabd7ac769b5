//! Wavefront error of one field: the optical path difference (OPD) of pupil rays against a
//! reference sphere, with piston and tilt removed, and its weighted RMS, the quantity of
//! an OPD merit (OpticStudio's default "wavefront, centroid" merit).
//!
//! Reference sphere: centred on the image point of the primary wavelength's chief ray,
//! through the paraxial exit pupil (as the FFT PSF's, `psf::pupil`). Every ray of every
//! wavelength is carried back from the image plane to that sphere. Piston is removed per
//! wavelength (wavelengths do not interfere); tilt, the wavefront's part that only moves
//! the image point (OPD = a L + b M for a reference centre moved by (a, b) / n'), per
//! wavelength as OpticStudio does (its merit then leaves lateral colour alone) or shared
//! by all wavelengths of the field (one image point per field: lateral colour counts).
//! Both are removed by weighted least squares over the transmitted rays with the caller's
//! pupil weights (e.g. a Gaussian quadrature's), so the RMS is that quadrature's estimate
//! of the RMS over the pupil.

use crate::aim::{Aiming, Beam};
use crate::error::{EngineError, Result};
use crate::lens::Lens;
use crate::psf::pupil::{back_to_sphere, reference};
use crate::trace::{Status, System};
use glam::DVec3;

/// How tilt is removed from the OPD of a field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tilt {
    /// One tilt per wavelength (OpticStudio's centroid reference).
    PerWavelength,
    /// One tilt for all wavelengths of the field (lateral colour stays in the OPD).
    Shared,
}

impl std::str::FromStr for Tilt {
    type Err = EngineError;
    fn from_str(s: &str) -> Result<Tilt> {
        match s {
            "wavelength" => Ok(Tilt::PerWavelength),
            "field" => Ok(Tilt::Shared),
            _ => Err(EngineError::Argument(format!(
                "tilt must be \"wavelength\" or \"field\", got \"{s}\""
            ))),
        }
    }
}

/// OPD of one field at several wavelengths; arrays are row-major (wavelength, ray).
pub struct FieldWavefront {
    pub n_rays: usize,
    /// OPD in waves of the ray's own wavelength, piston and tilt removed; 0 where the ray
    /// failed (status != 0).
    pub opd_waves: Vec<f64>,
    /// `Status as u8` per ray; a ray that passed the image but misses the reference
    /// sphere is `Missed`.
    pub status: Vec<u8>,
    /// Weighted RMS of `opd_waves` over the transmitted rays, per wavelength (waves).
    pub rms_waves: Vec<f64>,
    /// Tilt removed, per wavelength: (a, b) in mm of optical path per unit direction cosine.
    pub tilt_mm: Vec<[f64; 2]>,
    /// Chief-ray image point (primary wavelength) and reference-sphere radius, mm.
    pub chief_image: DVec3,
    pub radius: f64,
}

/// OPD of pupil rays (`px`, `py` normalized pupil coordinates, `weights` their pupil
/// weights) of one field at `wavelengths_nm`; `wavelength_weights` weigh the wavelengths
/// in a shared tilt fit.
#[allow(clippy::too_many_arguments)]
pub fn field_wavefront(
    lens: &Lens,
    field_deg: f64,
    wavelengths_nm: &[f64],
    wavelength_weights: &[f64],
    px: &[f64],
    py: &[f64],
    weights: &[f64],
    aiming: Aiming,
    tilt: Tilt,
) -> Result<FieldWavefront> {
    let n = px.len();
    if py.len() != n || weights.len() != n {
        return Err(EngineError::Argument(format!(
            "wavefront: px ({n}), py ({}) and weights ({}) differ in length",
            py.len(),
            weights.len()
        )));
    }
    if wavelengths_nm.is_empty() || wavelength_weights.len() != wavelengths_nm.len() {
        return Err(EngineError::Argument(format!(
            "wavefront: need >= 1 wavelength and one weight each, got {} and {}",
            wavelengths_nm.len(),
            wavelength_weights.len()
        )));
    }
    if let Some(w) = weights
        .iter()
        .chain(wavelength_weights)
        .find(|w| !(w.is_finite() && **w >= 0.0))
    {
        return Err(EngineError::Argument(format!(
            "wavefront: weight {w} is not finite and >= 0"
        )));
    }
    let flat = crate::image::flat_at_field(lens, field_deg, aiming)?;
    let lens: &Lens = &flat;
    let sys0 = System::new(lens, lens.primary_nm)?;
    let beam0 = Beam::new(&sys0, field_deg, aiming)?;
    let reference = reference(&beam0, &beam0.launch(0.0, 0.0))?;
    let (centre, radius) = (reference.chief.p, reference.radius);

    let nw = wavelengths_nm.len();
    let mut opl = vec![0.0; nw * n];
    let mut lm = vec![[0.0f64; 2]; nw * n];
    let mut status = vec![0u8; nw * n];
    for (w, &wl) in wavelengths_nm.iter().enumerate() {
        let sys = System::new(lens, wl)?;
        let beam = Beam::new(&sys, field_deg, aiming)?;
        let n_img = sys.image_index();
        let t = beam.trace_pupil_soa(px, py);
        let v3 = |a: &[f64], k: usize| DVec3::new(a[3 * k], a[3 * k + 1], a[3 * k + 2]);
        for k in 0..n {
            let j = w * n + k;
            status[j] = t.status[k];
            if t.status[k] != Status::Ok as u8 {
                continue;
            }
            let (pos, dir) = (v3(&t.position, k), v3(&t.direction, k));
            let Some(back) = back_to_sphere(pos, dir, centre, radius) else {
                status[j] = Status::Missed as u8;
                continue;
            };
            opl[j] = t.opl[k] + beam.wavefront_offset(v3(&t.origin, k)) + n_img * back;
            let u = (centre - (pos + back * dir)) / radius;
            lm[j] = [u.x, u.y];
        }
    }

    // Weighted least squares of the OPD (in waves) on piston (per wavelength) and tilt:
    // each wavelength's data centred on its weighted mean removes its piston; the tilt
    // then solves a 2x2 system over one wavelength or over all.
    let lambda: Vec<f64> = wavelengths_nm.iter().map(|w| w * 1e-6).collect();
    let q = |w: usize, k: usize| -> f64 {
        if status[w * n + k] == Status::Ok as u8 {
            weights[k] / (lambda[w] * lambda[w])
        } else {
            0.0
        }
    };
    let mut mean = vec![[0.0f64; 3]; nw]; // weighted means of (opl, L, M)
    for (w, m) in mean.iter_mut().enumerate() {
        let mut s = 0.0;
        for k in 0..n {
            let (qk, j) = (q(w, k), w * n + k);
            s += qk;
            m[0] += qk * opl[j];
            m[1] += qk * lm[j][0];
            m[2] += qk * lm[j][1];
        }
        if s > 0.0 {
            m.iter_mut().for_each(|v| *v /= s);
        }
    }
    // Normal equations of the tilt per wavelength: [[LL, LM], [LM, MM]] (a, b) = (LW, MW).
    let mut normal = vec![[0.0f64; 5]; nw];
    for (w, a) in normal.iter_mut().enumerate() {
        for k in 0..n {
            let (qk, j) = (q(w, k), w * n + k);
            let (l, m, o) = (lm[j][0] - mean[w][1], lm[j][1] - mean[w][2], opl[j] - mean[w][0]);
            a[0] += qk * l * l;
            a[1] += qk * l * m;
            a[2] += qk * m * m;
            a[3] += qk * l * o;
            a[4] += qk * m * o;
        }
    }
    let solve = |a: [f64; 5]| -> [f64; 2] {
        let det = a[0] * a[2] - a[1] * a[1];
        if det.abs() > 1e-12 * (a[0] * a[2]).abs().max(1e-300) {
            [(a[2] * a[3] - a[1] * a[4]) / det, (a[0] * a[4] - a[1] * a[3]) / det]
        } else if a[0] > 0.0 {
            [a[3] / a[0], 0.0] // a line of points: only one tilt is defined
        } else if a[2] > 0.0 {
            [0.0, a[4] / a[2]]
        } else {
            [0.0, 0.0]
        }
    };
    let tilt_mm: Vec<[f64; 2]> = match tilt {
        Tilt::PerWavelength => normal.iter().map(|a| solve(*a)).collect(),
        Tilt::Shared => {
            let mut sum = [0.0f64; 5];
            for (a, ww) in normal.iter().zip(wavelength_weights) {
                sum.iter_mut().zip(a).for_each(|(s, v)| *s += ww * v);
            }
            vec![solve(sum); nw]
        }
    };
    let mut opd_waves = vec![0.0; nw * n];
    let mut rms_waves = vec![0.0; nw];
    for w in 0..nw {
        let [a, b] = tilt_mm[w];
        let (mut s, mut ws) = (0.0, 0.0);
        for (k, &wk) in weights.iter().enumerate().take(n) {
            let j = w * n + k;
            if status[j] != Status::Ok as u8 {
                continue;
            }
            let r = (opl[j] - mean[w][0] - a * (lm[j][0] - mean[w][1]) - b * (lm[j][1] - mean[w][2])) / lambda[w];
            opd_waves[j] = r;
            s += wk * r * r;
            ws += wk;
        }
        rms_waves[w] = if ws > 0.0 { (s / ws).sqrt() } else { 0.0 };
    }
    Ok(FieldWavefront {
        n_rays: n,
        opd_waves,
        status,
        rms_waves,
        tilt_mm,
        chief_image: centre,
        radius,
    })
}
