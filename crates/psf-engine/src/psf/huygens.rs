//! Huygens PSF: a direct sum of spherical wavelets from points on the exit-pupil
//! reference sphere to each image-plane pixel, with no far-field approximation:
//!
//!   U(X) = sum_j w_j exp(i [2 pi W_j + k n (|X - S_j| - R)]),  w_j = (n/lambda) sqrt(f_j J_j)
//!
//! (the same weights as the FFT PSF, so the two agree wherever the FFT's assumptions hold).
//! For speed the distance is expanded about the chief-ray image point P: with
//! X = P + (dx, dy, 0) and u_j the unit vector from S_j to P,
//!   |X - S_j| = R + u.d + (|d|^2 - (u.d)^2) / 2R + O(|d|^3 / R^2).
//! The x and y parts are separable; the cross term -u_x u_y dx dy / R is expanded in a
//! short Taylor series, so the whole sum is one complex matrix product (matrixmultiply).
//! Where the neglected cubic term could exceed 0.01 rad the exact sum is evaluated instead.

use super::pupil::Pupil;
use super::{factorial, Diagnostics, PsfOptions};
use crate::error::Result;
use glam::DVec3;
use num_complex::{Complex32, Complex64};
use rayon::prelude::*;
use std::f64::consts::PI;

pub const CUBIC_TOL_RAD: f64 = 1e-2;
const CROSS_TOL_RAD: f64 = 1e-4;

struct Wavelet {
    s: DVec3,
    w: f64,
    /// Phase at the chief-ray point P.
    base: f64,
    r0: f64,
    u: DVec3,
}

fn wavelets(p: &Pupil, k: f64) -> Vec<Wavelet> {
    let amp = p.n_image / p.wavelength_mm;
    (0..p.valid.len())
        .filter(|&j| p.valid[j])
        .map(|j| {
            let dvec = p.chief - p.sphere[j];
            let r0 = dvec.length();
            Wavelet {
                s: p.sphere[j],
                w: amp * (p.flux[j] * p.jacobian[j]).sqrt(),
                base: 2.0 * PI * p.opd_waves[j] + k * (r0 - p.radius),
                r0,
                u: dvec / r0,
            }
        })
        .collect()
}

fn exact_field(ws: &[Wavelet], k: f64, x: DVec3) -> Complex64 {
    ws.iter()
        .map(|w| Complex64::from_polar(w.w, w.base + k * ((x - w.s).length() - w.r0)))
        .sum()
}

/// Phasors exp(i (a t + b t^2)) for t = (c - h) * pitch, c = 0..len, by recurrence.
fn chirp(out: &mut [Complex32], a: f64, b: f64, h: f64, pitch: f64) {
    let t0 = -h * pitch;
    let mut z = Complex64::from_polar(1.0, a * t0 + b * t0 * t0);
    let mut ratio = Complex64::from_polar(1.0, a * pitch + b * pitch * pitch * (2.0 * (-h) + 1.0));
    let step = Complex64::from_polar(1.0, 2.0 * b * pitch * pitch);
    for o in out.iter_mut() {
        *o = Complex32::new(z.re as f32, z.im as f32);
        z *= ratio;
        ratio *= step;
    }
}

pub fn huygens_psf(p: &Pupil, o: &PsfOptions, d: &mut Diagnostics) -> Result<(Vec<f64>, f64)> {
    let s = o.size;
    let pitch = o.pixel_mm;
    let k = 2.0 * PI * p.n_image / p.wavelength_mm;
    let ws = wavelets(p, k);
    let jn = ws.len();
    let h = (s / 2) as f64;
    let dmax = (h + 0.5) * pitch * 2f64.sqrt();
    let cubic = k * dmax.powi(3) / (2.0 * p.radius * p.radius);
    let peak_ref: f64 = ws.iter().map(|w| w.w).sum();
    let pixel = |r: usize, c: usize| p.chief + DVec3::new((c as f64 - h) * pitch, (r as f64 - h) * pitch, 0.0);
    d.set("huygens_cubic_phase_bound_rad", cubic);

    let prog = o.progress.as_deref();
    let stopped = || prog.is_some_and(|p| p.cancelled());
    let field: Vec<Complex64> = if cubic > CUBIC_TOL_RAD || o.huygens_exact {
        d.set("huygens_evaluation", "exact");
        prog.inspect(|p| p.start(s));
        let mut field = vec![Complex64::new(0.0, 0.0); s * s];
        field.par_chunks_mut(s).enumerate().for_each(|(r, row)| {
            if stopped() {
                return;
            }
            row.iter_mut()
                .enumerate()
                .for_each(|(c, v)| *v = exact_field(&ws, k, pixel(r, c)));
            prog.inspect(|p| p.step());
        });
        field
    } else {
        d.set("huygens_evaluation", "separable");
        let half = (h + 0.5) * pitch;
        let eps = ws
            .iter()
            .map(|w| k * w.u.x.abs() * w.u.y.abs() / w.r0)
            .fold(0.0, f64::max)
            * half
            * half;
        let mut terms = 1;
        while terms < 8 && eps.powi(terms as i32) / factorial(terms) > CROSS_TOL_RAD {
            terms += 1;
        }
        d.set("huygens_cross_terms", terms as f64);
        let kk = jn * terms;
        // A: s x kk column-major (y factors); B: kk x s row-major (x factors and weights).
        let mut a = vec![Complex32::new(0.0, 0.0); kk * s];
        let mut b = vec![Complex32::new(0.0, 0.0); kk * s];
        let offs: Vec<f64> = (0..s).map(|c| (c as f64 - h) * pitch).collect();
        a.par_chunks_mut(s)
            .zip(b.par_chunks_mut(s))
            .enumerate()
            .for_each(|(idx, (ac, bc))| {
                let (t, j) = (idx / jn, idx % jn);
                let w = &ws[j];
                chirp(ac, k * w.u.y, k * (1.0 - w.u.y * w.u.y) / (2.0 * w.r0), h, pitch);
                chirp(bc, k * w.u.x, k * (1.0 - w.u.x * w.u.x) / (2.0 * w.r0), h, pitch);
                let kappa = -k * w.u.x * w.u.y / w.r0;
                let coef =
                    Complex64::from_polar(w.w, w.base) * Complex64::new(0.0, kappa).powi(t as i32) / factorial(t);
                let coef = Complex32::new(coef.re as f32, coef.im as f32);
                for (c, v) in bc.iter_mut().enumerate() {
                    *v *= coef * (offs[c].powi(t as i32) as f32);
                }
                if t > 0 {
                    for (r, v) in ac.iter_mut().enumerate() {
                        *v *= offs[r].powi(t as i32) as f32;
                    }
                }
            });
        let mut u = vec![Complex32::new(0.0, 0.0); s * s];
        // Blocks of rows, one per thread, or of at most 64 rows where progress is watched.
        let blocks = rayon::current_num_threads()
            .max(1)
            .max(if prog.is_some() { s.div_ceil(64) } else { 1 })
            .min(s);
        let rows_per = s.div_ceil(blocks);
        prog.inspect(|p| p.start(s.div_ceil(rows_per)));
        u.par_chunks_mut(rows_per * s).enumerate().for_each(|(bi, uc)| {
            if stopped() {
                return;
            }
            let r0 = bi * rows_per;
            let m = uc.len() / s;
            // SAFETY: pointers and strides describe the live buffers a (s x kk, column-major,
            // rows r0..r0+m), b (kk x s, row-major) and uc (m x s, row-major).
            unsafe {
                matrixmultiply::cgemm(
                    matrixmultiply::CGemmOption::Standard,
                    matrixmultiply::CGemmOption::Standard,
                    m,
                    kk,
                    s,
                    [1.0, 0.0],
                    a.as_ptr().add(r0) as *const [f32; 2],
                    1,
                    s as isize,
                    b.as_ptr() as *const [f32; 2],
                    s as isize,
                    1,
                    [0.0, 0.0],
                    uc.as_mut_ptr() as *mut [f32; 2],
                    s as isize,
                    1,
                );
            }
            prog.inspect(|p| p.step());
        });
        u.iter().map(|z| Complex64::new(z.re as f64, z.im as f64)).collect()
    };
    if stopped() {
        return Err(crate::error::EngineError::Psf("Huygens PSF cancelled".into()));
    }
    let area = pitch * pitch;
    let out: Vec<f64> = field.iter().map(|z| z.norm_sqr() * area).collect();
    // Strehl from the sampled peak refined at the parabolic vertex with the exact sum.
    let (imax, vmax) = out
        .iter()
        .enumerate()
        .fold((0, f64::MIN), |acc, (i, &v)| if v > acc.1 { (i, v) } else { acc });
    let (ry, rx) = (imax / s, imax % s);
    let at = |r: usize, c: usize| out[r.min(s - 1) * s + c.min(s - 1)];
    let ox = if rx > 0 && rx + 1 < s {
        super::parabolic_offset(at(ry, rx - 1), vmax, at(ry, rx + 1))
    } else {
        0.0
    };
    let oy = if ry > 0 && ry + 1 < s {
        super::parabolic_offset(at(ry - 1, rx), vmax, at(ry + 1, rx))
    } else {
        0.0
    };
    let xr = p.chief + DVec3::new((rx as f64 - h + ox) * pitch, (ry as f64 - h + oy) * pitch, 0.0);
    let peak = exact_field(&ws, k, xr).norm_sqr().max(vmax / area);
    let strehl = peak / (peak_ref * peak_ref);
    let transmitted = p.transmitted_fraction();
    let window_energy: f64 = out.iter().sum();
    d.set(
        "energy_in_window",
        if transmitted > 0.0 {
            window_energy / transmitted
        } else {
            0.0
        },
    );
    Ok((out, strehl))
}
