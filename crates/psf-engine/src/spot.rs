//! Spot diagrams and relative illumination on a polar midpoint grid: ring i of `rings`
//! sits at radius (i - 1/2)/rings with 6(2i - 1) rays, so every ray stands for the same
//! pupil area and sums over the pupil converge as 1/rings^2 (a hexapolar grid with rays on
//! the rim converges as 1/rings).

use crate::aim::{Aiming, Beam};
use crate::error::{EngineError, Result};
use crate::lens::Lens;
use crate::trace::{End, System};

pub fn polar_grid(rings: usize) -> (Vec<f64>, Vec<f64>) {
    let (mut px, mut py) = (vec![], vec![]);
    for i in 1..=rings {
        let r = (i as f64 - 0.5) / rings as f64;
        let k = 6 * (2 * i - 1);
        let phase = if i % 2 == 0 { 0.5 } else { 0.0 };
        for q in 0..k {
            let a = 2.0 * std::f64::consts::PI * (q as f64 + phase) / k as f64;
            px.push(r * a.cos());
            py.push(r * a.sin());
        }
    }
    (px, py)
}

#[derive(Clone, Debug, Default)]
pub struct Spot {
    /// Image-plane points (x, y) of transmitted rays, and their flux weights.
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub w: Vec<f64>,
    pub chief_x: f64,
    pub chief_y: f64,
    /// Transmitted flux (mm^2 of entrance pupil projected on the beam).
    pub flux: f64,
    pub launched: usize,
}

pub fn trace_spot(lens: &Lens, field_deg: f64, wavelength_nm: f64, rings: usize, aiming: Aiming) -> Result<Spot> {
    let sys = System::new(lens, wavelength_nm)?;
    let beam = Beam::new(&sys, field_deg, aiming)?;
    let c = beam.launch(0.0, 0.0);
    let chief = sys.trace(c.origin, beam.dir, End::Image);
    let (px, py) = polar_grid(rings);
    let (launches, rays) = beam.trace_pupil(&px, &py);
    let mut s = Spot { chief_x: chief.p.x, chief_y: chief.p.y, launched: px.len(), ..Default::default() };
    let cell = std::f64::consts::PI / px.len() as f64;
    for (l, r) in launches.iter().zip(&rays) {
        if r.ok() {
            let w = beam.flux_weight(l) * cell;
            s.x.push(r.p.x);
            s.y.push(r.p.y);
            s.w.push(w);
            s.flux += w;
        }
    }
    if !chief.ok() && s.w.is_empty() {
        return Err(EngineError::Trace(format!("no ray reaches the image at {field_deg} deg, {wavelength_nm} nm")));
    }
    Ok(s)
}

/// Weighted RMS radius about the common centroid of several spots (mm).
pub fn rms_radius(spots: &[(&Spot, f64)]) -> f64 {
    let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
    for (s, wt) in spots {
        let norm = wt / s.flux.max(1e-300);
        for i in 0..s.x.len() {
            sx += norm * s.w[i] * s.x[i];
            sy += norm * s.w[i] * s.y[i];
            sw += norm * s.w[i];
        }
    }
    let (cx, cy) = (sx / sw, sy / sw);
    let mut v = 0.0;
    for (s, wt) in spots {
        let norm = wt / s.flux.max(1e-300);
        for i in 0..s.x.len() {
            v += norm * s.w[i] * ((s.x[i] - cx).powi(2) + (s.y[i] - cy).powi(2));
        }
    }
    (v / sw).sqrt()
}

/// Image irradiance at a field relative to the axis: transmitted flux ratio times the
/// ratio of image area per unit object solid angle, f^2 / (y dy/dtheta / sin theta), from
/// the real chief ray (so distortion and the cos^4 law come out of the trace).
pub fn relative_illumination(lens: &Lens, field_deg: f64, wavelength_nm: f64, rings: usize, aiming: Aiming) -> Result<f64> {
    let on_axis = trace_spot(lens, 0.0, wavelength_nm, rings, aiming)?;
    let here = trace_spot(lens, field_deg, wavelength_nm, rings, aiming)?;
    if on_axis.flux <= 0.0 {
        return Err(EngineError::Trace(format!("no on-axis ray reaches the image at {wavelength_nm} nm")));
    }
    Ok(here.flux / on_axis.flux * area_ratio(lens, field_deg, wavelength_nm, aiming)?)
}

/// The area factor of `relative_illumination`: f^2 sin(theta) / (y dy/dtheta) from the
/// real chief ray (1 on axis).
pub(crate) fn area_ratio(lens: &Lens, field_deg: f64, wavelength_nm: f64, aiming: Aiming) -> Result<f64> {
    let t = field_deg.to_radians().abs();
    let area_ratio = if t < 1e-6 {
        1.0
    } else {
        let sys = System::new(lens, wavelength_nm)?;
        let chief_y = |deg: f64| -> Result<f64> {
            let b = Beam::new(&sys, deg, aiming)?;
            let r = sys.trace(b.launch(0.0, 0.0).origin, b.dir, End::Image);
            if r.ok() {
                Ok(r.p.y)
            } else {
                Err(EngineError::Trace(format!("chief ray at {deg} deg fails ({:?} at surface {})", r.status, r.surface + 1)))
            }
        };
        let h = 1e-4;
        let y = chief_y(field_deg.abs())?;
        let dy = (chief_y((t + h).to_degrees())? - chief_y((t - h).to_degrees())?) / (2.0 * h);
        let f = crate::paraxial::paraxial(lens, wavelength_nm)?.efl;
        f * f * t.sin() / (y * dy)
    };
    Ok(area_ratio)
}

/// Polychromatic spot summary for one field: RMS radius about the common centroid,
/// per-wavelength RMS, vignetting and relative illumination (wavelength-weighted).
pub fn spot_summary(lens: &Lens, field_deg: f64, wavelengths_nm: &[f64], weights: &[f64], rings: usize, aiming: Aiming) -> Result<serde_json::Value> {
    let spots = wavelengths_nm.iter().map(|&wl| trace_spot(lens, field_deg, wl, rings, aiming)).collect::<Result<Vec<_>>>()?;
    let pairs: Vec<(&Spot, f64)> = spots.iter().zip(weights.iter().copied()).filter(|(s, _)| s.flux > 0.0).collect();
    if pairs.is_empty() {
        return Err(EngineError::Trace(format!("no ray reaches the image at {field_deg} deg")));
    }
    let wsum: f64 = weights.iter().sum();
    let mut vig = 0.0;
    let mut ri = 0.0;
    let mut per = vec![];
    for ((s, &w), &wl) in spots.iter().zip(weights).zip(wavelengths_nm) {
        per.push(if s.flux > 0.0 { rms_radius(&[(s, 1.0)]) * 1e3 } else { f64::NAN });
        vig += w / wsum * s.x.len() as f64 / s.launched as f64;
        ri += w / wsum * relative_illumination(lens, field_deg, wl, rings.min(32), aiming)?;
    }
    let (n_ok, n_rays): (usize, usize) = (spots.iter().map(|s| s.x.len()).sum(), spots.iter().map(|s| s.launched).sum());
    let cx: f64 = pairs.iter().map(|(s, w)| w * s.x.iter().zip(&s.w).map(|(x, q)| x * q).sum::<f64>() / s.flux).sum::<f64>() / pairs.iter().map(|p| p.1).sum::<f64>();
    let cy: f64 = pairs.iter().map(|(s, w)| w * s.y.iter().zip(&s.w).map(|(y, q)| y * q).sum::<f64>() / s.flux).sum::<f64>() / pairs.iter().map(|p| p.1).sum::<f64>();
    let primary = spots.get(wavelengths_nm.len() / 2).unwrap_or(&spots[0]);
    Ok(serde_json::json!({
        "field_deg": field_deg,
        "rms_um": rms_radius(&pairs) * 1e3,
        "rms_um_per_wavelength": per.into_iter().map(|v| if v.is_finite() { serde_json::json!(v) } else { serde_json::Value::Null }).collect::<Vec<_>>(),
        "centroid_x_mm": cx, "centroid_y_mm": cy, "chief_y_mm": primary.chief_y,
        "n_rays": n_rays, "n_ok": n_ok, "vignetting": vig, "relative_illumination": ri,
    }))
}
