//! PSF by FFT of the pupil function (paper Eq. 1), in the direction-cosine form that stays
//! right off axis. The image-plane field is the Fourier transform of the exit-pupil field
//! over the image-space direction cosines (L, M):
//!
//!   U(x, y) = (n/lambda) sum_j sqrt(f_j J_j) exp(i 2 pi W_j) exp(i k n (L_j x + M_j y)),
//!
//! with W_j the OPD (waves) against the reference sphere, f_j the ray's flux and J_j the
//! local |d(L,M)/d(grid)|. A single FFT needs L and M linear in the grid indices; off axis
//! the exit pupil is anamorphic (different scales in x and y), which we honour with separate
//! x and y pitches, and distorted, which we handle exactly by a Taylor series of the
//! residual exp(i k n (dL x + dM y)): each order is one more FFT, and the order is chosen
//! from the largest residual phase over the output window.

use super::pupil::Pupil;
use super::{resample, Diagnostics, PsfOptions};
use crate::error::{EngineError, Result};
use num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::cell::RefCell;
use std::f64::consts::PI;
use std::sync::Arc;

thread_local! {
    static PLANNER: RefCell<FftPlanner<f64>> = RefCell::new(FftPlanner::new());
}

fn plan(len: usize) -> Arc<dyn Fft<f64>> {
    PLANNER.with(|p| p.borrow_mut().plan_fft_inverse(len))
}

/// Largest Taylor order for the pupil-distortion correction, and its target phase error.
const MAX_ORDER: usize = 8;
const TAYLOR_TOL_RAD: f64 = 1e-3;
const MAX_GRID: usize = 8192;

pub struct AffineMap {
    pub l0: f64,
    pub lx: f64,
    pub m0: f64,
    pub my: f64,
}

/// Least-squares L = l0 + lx a + ..., M = m0 + my b + ... over valid samples (a, b indices).
pub fn fit_affine(p: &Pupil) -> AffineMap {
    let n = p.n;
    let mut ata = [[0.0f64; 3]; 3];
    let (mut bl, mut bm) = ([0.0f64; 3], [0.0f64; 3]);
    for b in 0..n {
        for a in 0..n {
            let j = b * n + a;
            if !p.valid[j] {
                continue;
            }
            let row = [1.0, a as f64, b as f64];
            for r in 0..3 {
                for c in 0..3 {
                    ata[r][c] += row[r] * row[c];
                }
                bl[r] += row[r] * p.l[j];
                bm[r] += row[r] * p.m[j];
            }
        }
    }
    let cl = super::pupil::solve3(ata, bl);
    let cm = super::pupil::solve3(ata, bm);
    match (cl, cm) {
        (Some(cl), Some(cm)) if cl[1].abs() > 0.0 && cm[2].abs() > 0.0 => AffineMap { l0: cl[0], lx: cl[1], m0: cm[0], my: cm[2] },
        // Degenerate pupils (a single row of rays): fall back to the mean Jacobian.
        _ => {
            let jm = (p.jacobian.iter().zip(&p.valid).filter(|(_, v)| **v).map(|(j, _)| *j).sum::<f64>() / p.n_valid() as f64).sqrt();
            AffineMap { l0: 0.0, lx: jm, m0: 0.0, my: jm }
        }
    }
}

fn factorial(k: usize) -> f64 {
    (1..=k).map(|i| i as f64).product()
}

pub fn fft_psf(p: &Pupil, o: &PsfOptions, d: &mut Diagnostics) -> Result<(Vec<f64>, f64)> {
    let n = p.n;
    let k = 2.0 * PI * p.n_image / p.wavelength_mm;
    let map = fit_affine(p);
    // Default grid: 4x zero padding, more where needed for a native pitch of at most half
    // the output pixel (so the cubic resampling stays accurate), capped at 8192.
    let field = p.wavelength_mm / (p.n_image * map.lx.abs().min(map.my.abs()));
    let want = (2.0 * field / o.pixel_mm).ceil() as usize;
    let g = o.fft_grid.unwrap_or_else(|| (4 * n).max(want.next_power_of_two()).min(MAX_GRID.max(4 * n)));
    if o.fft_grid.is_none() && g < want {
        d.warn(format!("FFT grid capped at {g}: the native pitch exceeds half the output pixel; the resampled PSF is approximate"));
    }
    if g < n {
        return Err(EngineError::Argument(format!("fft_grid {g} is smaller than pupil_samples {n}")));
    }
    if g < 2 * n {
        d.warn(format!("fft_grid {g} < 2 x pupil_samples {n}: the intensity is sampled below Nyquist and aliases"));
    }
    let dx = p.wavelength_mm / (p.n_image * g as f64 * map.lx.abs());
    let dy = p.wavelength_mm / (p.n_image * g as f64 * map.my.abs());
    let sgn_x = map.lx.signum();
    let sgn_y = map.my.signum();

    // Pupil field and residual direction cosines.
    let amp = p.n_image / p.wavelength_mm;
    let mut field = vec![Complex64::new(0.0, 0.0); n * n];
    let mut res_l = vec![0.0; n * n];
    let mut res_m = vec![0.0; n * n];
    let mut peak_ref = 0.0;
    let (mut max_rl, mut max_rm) = (0.0f64, 0.0f64);
    for b in 0..n {
        for a in 0..n {
            let j = b * n + a;
            if !p.valid[j] {
                continue;
            }
            let w = amp * (p.flux[j] * p.jacobian[j]).sqrt();
            peak_ref += w;
            field[j] = Complex64::from_polar(w, 2.0 * PI * p.opd_waves[j]);
            res_l[j] = p.l[j] - map.l0 - map.lx * a as f64;
            res_m[j] = p.m[j] - map.m0 - map.my * b as f64;
            max_rl = max_rl.max(res_l[j].abs());
            max_rm = max_rm.max(res_m[j].abs());
        }
    }
    // Residual phase bound over the output window decides the Taylor order.
    let half_x = (o.size as f64 / 2.0 + 0.5) * o.pixel_mm;
    let eps = k * (max_rl * half_x + max_rm * half_x);
    let mut order = 0;
    while order < MAX_ORDER && eps.powi(order as i32 + 1) / factorial(order + 1) > TAYLOR_TOL_RAD {
        order += 1;
    }
    let trunc = eps.powi(order as i32 + 1) / factorial(order + 1);
    if trunc > TAYLOR_TOL_RAD {
        d.warn(format!(
            "exit pupil too distorted for the FFT PSF over this window (residual phase up to {eps:.2} rad, order-{order} error {trunc:.2e} rad): use method=huygens"
        ));
    }
    d.set("pupil_distortion_rad", eps);
    d.set("distortion_order", order as f64);

    // Accumulate sum_{p+q<=order} (i k)^(p+q)/(p! q!) x^p y^q FFT[field dL^p dM^q].
    let fft = plan(g);
    let mut u = vec![Complex64::new(0.0, 0.0); g * g];
    let mut rows = vec![Complex64::new(0.0, 0.0); n * g];
    let mut cols = vec![Complex64::new(0.0, 0.0); g * g];
    let mut scratch = vec![Complex64::new(0.0, 0.0); fft.get_inplace_scratch_len()];
    let xs: Vec<f64> = (0..g).map(|m| if m < g / 2 { m as f64 } else { m as f64 - g as f64 } * dx * sgn_x).collect();
    let ys: Vec<f64> = (0..g).map(|m| if m < g / 2 { m as f64 } else { m as f64 - g as f64 } * dy * sgn_y).collect();
    for tot in 0..=order {
        for pp in 0..=tot {
            let qq = tot - pp;
            // Rows (b) of length g holding field * dL^p * dM^q, zero padded.
            rows.iter_mut().for_each(|v| *v = Complex64::new(0.0, 0.0));
            for b in 0..n {
                for a in 0..n {
                    let j = b * n + a;
                    if p.valid[j] {
                        rows[b * g + a] = field[j] * (res_l[j].powi(pp as i32) * res_m[j].powi(qq as i32));
                    }
                }
            }
            for r in rows.chunks_exact_mut(g) {
                fft.process_with_scratch(r, &mut scratch);
            }
            // Transpose into columns (x index major) and transform along y.
            cols.iter_mut().for_each(|v| *v = Complex64::new(0.0, 0.0));
            for b in 0..n {
                for m in 0..g {
                    cols[m * g + b] = rows[b * g + m];
                }
            }
            for c in cols.chunks_exact_mut(g) {
                fft.process_with_scratch(c, &mut scratch);
            }
            let coef = Complex64::new(0.0, k).powi(tot as i32) / (factorial(pp) * factorial(qq));
            for nrow in 0..g {
                let yq = ys[nrow].powi(qq as i32);
                for m in 0..g {
                    let f = coef * (xs[m].powi(pp as i32) * yq);
                    u[nrow * g + m] += f * cols[m * g + nrow];
                }
            }
        }
    }
    // Native intensity, shifted so the chief-ray point sits at index g/2. With a negative
    // pitch sign the axis is mirrored so that the array still runs along +x / +y.
    let mut native = vec![0.0; g * g];
    for nrow in 0..g {
        let ny = if sgn_y > 0.0 { (nrow + g / 2) % g } else { (g / 2 + g - nrow) % g };
        for m in 0..g {
            let mx = if sgn_x > 0.0 { (m + g / 2) % g } else { (g / 2 + g - m) % g };
            native[ny * g + mx] = u[nrow * g + m].norm_sqr();
        }
    }
    let native_energy: f64 = native.iter().sum::<f64>() * dx * dy;
    // Strehl: sampled peak refined by the exact direct sum at the parabolic vertex.
    let (imax, _) = native.iter().enumerate().fold((0, f64::MIN), |a, (i, &v)| if v > a.1 { (i, v) } else { a });
    let (ry, rx) = (imax / g, imax % g);
    let at = |yy: isize, xx: isize| native[(yy.rem_euclid(g as isize) as usize) * g + xx.rem_euclid(g as isize) as usize];
    let (iy, ix) = (ry as isize, rx as isize);
    let fx = (rx as f64 - (g / 2) as f64 + super::parabolic_offset(at(iy, ix - 1), at(iy, ix), at(iy, ix + 1))) * dx;
    let fy = (ry as f64 - (g / 2) as f64 + super::parabolic_offset(at(iy - 1, ix), at(iy, ix), at(iy + 1, ix))) * dy;
    let peak = direct_intensity(p, amp, k, fx, fy).max(native[imax]);
    let strehl = peak / (peak_ref * peak_ref);

    // Resample onto the requested detector grid.
    let c_out = (o.size / 2) as f64;
    let weights = if o.integrate { resample::weights_1d } else { resample::point_weights_1d };
    let wx = weights(g, dx, (g / 2) as f64, o.size, o.pixel_mm, c_out);
    let wy = weights(g, dy, (g / 2) as f64, o.size, o.pixel_mm, c_out);
    let mut out = resample::apply(&native, g, &wy, &wx);
    if !o.integrate {
        out.iter_mut().for_each(|v| *v = v.max(0.0));
    }
    // Normalize explicitly: total energy equals the transmitted flux fraction.
    let transmitted = p.transmitted_fraction();
    let scale = if native_energy > 0.0 { transmitted / native_energy } else { 0.0 };
    out.iter_mut().for_each(|v| *v *= scale);
    let window_energy: f64 = out.iter().sum();
    let window_x = o.size as f64 * o.pixel_mm;
    let period_x = g as f64 * dx;
    let period_y = g as f64 * dy;
    if window_x > period_x.min(period_y) * 1.0001 {
        d.warn(format!(
            "output window {:.1} um exceeds the FFT field {:.1} x {:.1} um (lambda / pupil-sample spacing): increase pupil_samples",
            window_x * 1e3,
            period_x * 1e3,
            period_y * 1e3
        ));
    }
    // Geometric check for wrap-around: rays landing beyond half the FFT period alias.
    let (mut ex, mut ey) = (0.0f64, 0.0f64);
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        ex = ex.max((p.image[j].x - p.chief.x).abs());
        ey = ey.max((p.image[j].y - p.chief.y).abs());
    }
    if ex > 0.5 * period_x || ey > 0.5 * period_y {
        d.warn(format!(
            "spot extends to {:.1} x {:.1} um from the chief ray, beyond half the FFT field ({:.1} x {:.1} um): energy wraps around; increase pupil_samples",
            ex * 1e3,
            ey * 1e3,
            0.5 * period_x * 1e3,
            0.5 * period_y * 1e3
        ));
    }
    d.set("fft_grid", g as f64);
    d.set("native_pitch_x_um", dx * 1e3);
    d.set("native_pitch_y_um", dy * 1e3);
    d.set("fft_field_x_um", period_x * 1e3);
    d.set("fft_field_y_um", period_y * 1e3);
    d.set("spot_extent_x_um", ex * 1e3);
    d.set("spot_extent_y_um", ey * 1e3);
    d.set("energy_in_window", if transmitted > 0.0 { window_energy / transmitted } else { 0.0 });
    Ok((out, strehl))
}

/// |U(x, y)|^2 by the exact direct sum over pupil samples (no affine approximation).
pub fn direct_intensity(p: &Pupil, amp: f64, k: f64, x: f64, y: f64) -> f64 {
    let mut acc = Complex64::new(0.0, 0.0);
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        let w = amp * (p.flux[j] * p.jacobian[j]).sqrt();
        acc += Complex64::from_polar(w, 2.0 * PI * p.opd_waves[j] + k * (p.l[j] * x + p.m[j] * y));
    }
    acc.norm_sqr()
}
