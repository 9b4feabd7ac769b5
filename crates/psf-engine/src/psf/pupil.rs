//! Sampling the pupil for one field and wavelength: a square grid of rays over the unit
//! pupil (cell centres inside the unit circle), traced to the image plane, with each ray's
//! optical path difference against the reference sphere centred on the chief-ray image
//! point (radius: chief-ray distance to the paraxial exit pupil), its image-space direction
//! cosines, its flux, and the local Jacobian d(L, M)/d(grid index).

use crate::aim::{Aiming, Beam};
use crate::error::{EngineError, Result};
use crate::trace::{End, Status, System};
use glam::DVec3;

pub struct Pupil {
    /// Grid size (samples across the pupil diameter).
    pub n: usize,
    pub wavelength_mm: f64,
    /// Image-space refractive index.
    pub n_image: f64,
    /// Sample launched (inside the unit circle) and sample transmitted, row-major (row = y).
    pub inside: Vec<bool>,
    pub valid: Vec<bool>,
    /// OPD in waves relative to the chief ray (0 where not valid).
    pub opd_waves: Vec<f64>,
    /// Flux fraction of each sample: sums to 1 over the launched samples.
    pub flux: Vec<f64>,
    pub l: Vec<f64>,
    pub m: Vec<f64>,
    /// |d(L, M)/d(a, b)| per grid cell.
    pub jacobian: Vec<f64>,
    /// Points on the reference sphere and image-plane intercepts.
    pub sphere: Vec<DVec3>,
    pub image: Vec<DVec3>,
    pub chief: DVec3,
    pub chief_dir: DVec3,
    pub radius: f64,
    /// Launched flux (entrance-plane area x cos(field), mm^2), for relative illumination.
    pub launched_flux_mm2: f64,
    pub status_counts: [usize; 5],
}

impl Pupil {
    #[inline]
    pub fn coord(&self, i: usize) -> f64 {
        -1.0 + (2.0 * i as f64 + 1.0) / self.n as f64
    }

    pub fn transmitted_fraction(&self) -> f64 {
        self.flux.iter().zip(&self.valid).filter(|(_, v)| **v).map(|(f, _)| f).sum()
    }

    pub fn n_valid(&self) -> usize {
        self.valid.iter().filter(|v| **v).count()
    }

    /// Largest OPD change between neighbouring valid samples, in waves.
    pub fn max_phase_step(&self) -> f64 {
        let n = self.n;
        let mut worst = 0.0f64;
        for b in 0..n {
            for a in 0..n {
                let j = b * n + a;
                if !self.valid[j] {
                    continue;
                }
                if a + 1 < n && self.valid[j + 1] {
                    worst = worst.max((self.opd_waves[j + 1] - self.opd_waves[j]).abs());
                }
                if b + 1 < n && self.valid[j + n] {
                    worst = worst.max((self.opd_waves[j + n] - self.opd_waves[j]).abs());
                }
            }
        }
        worst
    }

    /// Flux-weighted RMS wavefront error (waves) with piston and tilt (in L, M) removed.
    pub fn rms_wavefront(&self) -> f64 {
        // Weighted least squares of W on (1, L, M).
        let mut ata = [[0.0f64; 3]; 3];
        let mut atb = [0.0f64; 3];
        for j in (0..self.valid.len()).filter(|&j| self.valid[j]) {
            let row = [1.0, self.l[j], self.m[j]];
            for r in 0..3 {
                for c in 0..3 {
                    ata[r][c] += self.flux[j] * row[r] * row[c];
                }
                atb[r] += self.flux[j] * row[r] * self.opd_waves[j];
            }
        }
        let coef = solve3(ata, atb).unwrap_or([atb[0] / ata[0][0].max(1e-300), 0.0, 0.0]);
        let (mut s, mut wsum) = (0.0, 0.0);
        for j in (0..self.valid.len()).filter(|&j| self.valid[j]) {
            let r = self.opd_waves[j] - coef[0] - coef[1] * self.l[j] - coef[2] * self.m[j];
            s += self.flux[j] * r * r;
            wsum += self.flux[j];
        }
        if wsum > 0.0 {
            (s / wsum).sqrt()
        } else {
            0.0
        }
    }
}

pub(crate) fn solve3(mut a: [[f64; 3]; 3], mut b: [f64; 3]) -> Option<[f64; 3]> {
    for col in 0..3 {
        let piv = (col..3).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for r in 0..3 {
            if r != col {
                let f = a[r][col] / a[col][col];
                for c in 0..3 {
                    a[r][c] -= f * a[col][c];
                }
                b[r] -= f * b[col];
            }
        }
    }
    Some([b[0] / a[0][0], b[1] / a[1][1], b[2] / a[2][2]])
}

/// Trace the chief ray and an n x n pupil grid for one field at the system's wavelength.
pub fn sample_pupil(sys: &System, field_deg: f64, aiming: Aiming, n: usize) -> Result<Pupil> {
    if n < 4 {
        return Err(EngineError::Argument(format!("pupil_samples = {n}: need at least 4")));
    }
    let beam = Beam::new(sys, field_deg, aiming)?;
    let chief_launch = beam.launch(0.0, 0.0);
    let chief = sys.trace(chief_launch.origin, beam.dir, End::Image);
    if !chief.ok() {
        return Err(EngineError::Trace(format!(
            "chief ray at {field_deg} deg, {:.1} nm: {:?} at surface {}",
            sys.wavelength_nm,
            chief.status,
            chief.surface + 1
        )));
    }
    let chief_opl = chief.opl + beam.wavefront_offset(chief_launch.origin);
    let n_img = sys.image_index();
    // Reference sphere through the chief ray's crossing of the paraxial exit-pupil plane.
    let z_xp = sys.lens.image_z + beam.par.exit_pupil_z;
    let radius = if beam.par.exit_pupil_z.is_finite() {
        let t = (z_xp - chief.p.z) / chief.d.z;
        (t * chief.d).length()
    } else {
        f64::INFINITY
    };
    if !(radius.is_finite() && radius > 0.0) {
        return Err(EngineError::Psf("exit pupil at infinity (image-space telecentric): reference sphere undefined".into()));
    }
    let coord = |i: usize| -1.0 + (2.0 * i as f64 + 1.0) / n as f64;
    let (mut px, mut py, mut idx) = (vec![], vec![], vec![]);
    for b in 0..n {
        for a in 0..n {
            let (x, y) = (coord(a), coord(b));
            if x * x + y * y <= 1.0 {
                px.push(x);
                py.push(y);
                idx.push(b * n + a);
            }
        }
    }
    let (launches, rays) = beam.trace_pupil(&px, &py);
    let nn = n * n;
    let mut p = Pupil {
        n,
        wavelength_mm: sys.wavelength_nm * 1e-6,
        n_image: n_img,
        inside: vec![false; nn],
        valid: vec![false; nn],
        opd_waves: vec![0.0; nn],
        flux: vec![0.0; nn],
        l: vec![0.0; nn],
        m: vec![0.0; nn],
        jacobian: vec![0.0; nn],
        sphere: vec![DVec3::ZERO; nn],
        image: vec![DVec3::ZERO; nn],
        chief: chief.p,
        chief_dir: chief.d,
        radius,
        launched_flux_mm2: 0.0,
        status_counts: [0; 5],
    };
    // The chief ray crosses the sphere a distance R before its image point.
    let chief_sphere_opl = chief_opl - n_img * radius;
    let cell = (2.0 / n as f64).powi(2);
    let mut total = 0.0;
    for ((&j, l), r) in idx.iter().zip(&launches).zip(&rays) {
        p.inside[j] = true;
        let f = beam.flux_weight(l) * cell;
        p.flux[j] = f;
        total += f;
        p.status_counts[r.status as usize] += 1;
        if r.status != Status::Ok {
            continue;
        }
        // Back along the ray from the image plane to the reference sphere (t < 0).
        let v = r.p - chief.p;
        let vd = v.dot(r.d);
        let disc = vd * vd - v.length_squared() + radius * radius;
        if disc < 0.0 {
            p.status_counts[Status::Ok as usize] -= 1;
            p.status_counts[Status::Missed as usize] += 1;
            continue;
        }
        let t = -vd - disc.sqrt();
        let opl = r.opl + beam.wavefront_offset(l.origin) + n_img * t;
        p.valid[j] = true;
        p.sphere[j] = r.p + t * r.d;
        p.image[j] = r.p;
        p.l[j] = r.d.x;
        p.m[j] = r.d.y;
        p.opd_waves[j] = (opl - chief_sphere_opl) / p.wavelength_mm;
    }
    p.launched_flux_mm2 = total;
    if total > 0.0 {
        p.flux.iter_mut().for_each(|f| *f /= total);
    }
    if p.n_valid() == 0 {
        return Err(EngineError::Psf(format!(
            "no ray of the {}-sample pupil reaches the image at {field_deg} deg, {:.1} nm (status counts ok/missed/clipped/TIR/invalid = {:?})",
            idx.len(),
            sys.wavelength_nm,
            p.status_counts
        )));
    }
    jacobians(&mut p);
    Ok(p)
}

/// d(L, M)/d(a, b) by central differences where both neighbours are valid, one-sided
/// otherwise, and the grid-average slope for isolated samples.
fn jacobians(p: &mut Pupil) {
    let n = p.n;
    let deriv = |v: &Vec<f64>, j: usize, step: usize, at_lo: bool, at_hi: bool| -> Option<f64> {
        let lo = !at_lo && p.valid[j - step];
        let hi = !at_hi && p.valid[j + step];
        match (lo, hi) {
            (true, true) => Some(0.5 * (v[j + step] - v[j - step])),
            (false, true) => Some(v[j + step] - v[j]),
            (true, false) => Some(v[j] - v[j - step]),
            _ => None,
        }
    };
    let mut jac = vec![0.0; n * n];
    let (mut sum, mut cnt) = (0.0, 0usize);
    for b in 0..n {
        for a in 0..n {
            let j = b * n + a;
            if !p.valid[j] {
                continue;
            }
            let la = deriv(&p.l, j, 1, a == 0, a + 1 == n);
            let ma = deriv(&p.m, j, 1, a == 0, a + 1 == n);
            let lb = deriv(&p.l, j, n, b == 0, b + 1 == n);
            let mb = deriv(&p.m, j, n, b == 0, b + 1 == n);
            if let (Some(la), Some(ma), Some(lb), Some(mb)) = (la, ma, lb, mb) {
                jac[j] = (la * mb - lb * ma).abs();
                sum += jac[j];
                cnt += 1;
            } else {
                jac[j] = -1.0;
            }
        }
    }
    let mean = if cnt > 0 { sum / cnt as f64 } else { 0.0 };
    for (j, v) in jac.iter_mut().enumerate() {
        if p.valid[j] && *v < 0.0 {
            *v = mean;
        }
    }
    p.jacobian = jac;
}
