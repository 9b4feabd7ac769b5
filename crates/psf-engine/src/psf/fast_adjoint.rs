//! The reverse pass of the fast FFT PSF with fitted pupils (psf/fast.rs): given g = dL/dPSF
//! for one field and wavelength, dL/d(lens parameters) in one pass, flat in their number.
//!
//! The forward pass maps the lens to its pupil fits (W, px, py as Legendre series in the
//! grid's coordinates u, v), the fits to the pupil function on the direction grid
//! P = sqrt|d(px, py)/d(u, v)| cov exp(i 2 pi W), and P by two transforms to U, the PSF
//! scale |U|^2. Backwards:
//!
//! 1. dL/dU = 2 scale g U on the window's bins (a bin feeds the pixel at +m and its mirror
//!    image at -m), then the transforms' adjoints (the forward FFT, where the forward pass
//!    ran the inverse one): the same columns and rows, one transform each.
//! 2. Each cell: dL/dW = 2 pi a (Im P' cos - Re P' sin), dL/da = Re P' cos + Im P' sin (P' the
//!    cell's adjoint, its mirror image's added); the amplitude's derivatives by the fits'
//!    values and slopes at the cell (the Jacobian's four slopes inside; at the rim, the
//!    edge coverage's dependence on px, py and their slopes too, in dual numbers).
//! 3. Those into the coefficients, row by row with the Legendre values at the cells
//!    (separable: P_i(u) P_j(v)).
//! 4. The coefficients' tangents along the lens parameters (`tangent::fits_along`, forward
//!    mode through the coarse rays, the aiming and the least squares) close the chain.
//!
//! The grid is held where the forward pass put it: its cells keep their (u, v), the scale rho
//! of u = L / rho held too (the fitted functions of the directions do not depend on it), so
//! the cell size and the intensity's scale are constants; the grid moves with the chief ray
//! (v = (M - M_chief) / rho), as the PSF's window does. Discrete choices (the grid size, the
//! fits' degree, the rim zone) are fixed at the forward pass's: the gradient is that of the
//! PSF with them fixed, which is the PSF's wherever they do not change.

use super::fast::{self, legendre, row_len, terms, FastState, RowSeries, Table, MAX_DEGREE};
use super::fft::{buffer, plan_adjoint, recycle, zero_fill};
use super::{Diagnostics, PsfOptions};
use crate::error::{arg, Result};
use crate::tangent::{fits_along, Dual, FitTangents, Param};
use crate::trace::System;
use num_complex::Complex32;
use std::f64::consts::PI;

/// A fast PSF and what its reverse pass needs: the forward pass's grid and field, and the
/// fits' tangents along the parameters.
pub struct Linearized<const N: usize> {
    /// The PSF (`fast::fast_psf`'s data).
    pub psf: Vec<f64>,
    state: Option<FastState>,
    fits: FitTangents<N>,
    size: usize,
}

impl<const N: usize> Linearized<N> {
    /// The gradient of sum(g * PSF) along the parameters (g: size x size values).
    pub fn vjp(&self, g: &[f64]) -> Result<[f64; N]> {
        if g.len() != self.size * self.size {
            return arg(format!(
                "fast PSF gradient: dL/dPSF holds {} values, expected {} x {}",
                g.len(),
                self.size,
                self.size
            ));
        }
        let st = self.state.as_ref().expect("held until dropped");
        let adj = coefficient_adjoints(st, g, self.size);
        let mut grad = [0.0; N];
        for (a, c) in [
            (&adj[0], &self.fits.w),
            (&adj[1], &self.fits.py),
            (&adj[2], &self.fits.px),
        ] {
            for (a, c) in a.iter().zip(c) {
                for (gk, dk) in grad.iter_mut().zip(&c.d) {
                    *gk += a * dk;
                }
            }
        }
        Ok(grad)
    }
}

impl<const N: usize> Drop for Linearized<N> {
    fn drop(&mut self) {
        if let Some(st) = self.state.take() {
            recycle(st.cols);
        }
    }
}

/// The fast PSF at `field_deg` (as `fast::fast_psf`, its diagnostics into `d`), linearized
/// along `params` (at most N). Ok(Err(reason)) where the fast path with fitted pupils does not
/// compute this PSF (a traced pupil, a fallback): no one-pass gradient then.
pub fn linearize<const N: usize>(
    sys: &System,
    field_deg: f64,
    o: &PsfOptions,
    params: &[Param],
    d: &mut Diagnostics,
) -> Result<std::result::Result<Linearized<N>, &'static str>> {
    if params.len() > N {
        return arg(format!("fast PSF gradient: {} parameters, at most {N}", params.len()));
    }
    let mut keep = None;
    let psf = match fast::fast_psf_kept(sys, field_deg, o, d, false, Some(&mut keep))? {
        Ok(out) => out,
        Err(why) => return Ok(Err(why)),
    };
    let Some(st) = keep else {
        return Ok(Err(
            "the pupil was traced cell by cell (its fits missed their tolerance): no one-pass gradient",
        ));
    };
    let fits = fits_along::<N>(sys, params, field_deg, st.degree, true);
    let fits = match fits {
        Ok(Some(f)) => f,
        Ok(None) => {
            recycle(st.cols);
            return Ok(Err("the fits' tangents could not be formed (a coarse ray lost)"));
        }
        Err(e) => {
            recycle(st.cols);
            return Err(e);
        }
    };
    Ok(Ok(Linearized {
        psf,
        state: Some(st),
        fits,
        size: o.size,
    }))
}

/// Horner in s over the first `n` coefficients.
#[inline]
fn series(c: &[f64], n: usize, s: f64) -> f64 {
    c[..n].iter().rev().fold(0.0, |a, &k| a * s + k)
}

/// `fast::cover_cell` in dual numbers (the same branches, taken on the values).
fn cover_dual<const N: usize>(r: Dual<N>, gx: Dual<N>, gy: Dual<N>) -> Dual<N> {
    let one = Dual::constant(1.0);
    let abs = |x: Dual<N>| if x.v < 0.0 { -x } else { x };
    let gn = (gx * gx + gy * gy).sqrt();
    let d = (one - r) / gn;
    let (ax, ay) = (abs(gx) / gn, abs(gy) / gn);
    let (a, b) = if ax.v >= ay.v { (ax, ay) } else { (ay, ax) };
    let (lo, hi) = ((a - b) * 0.5, (a + b) * 0.5);
    if r.v < 0.5 || d.v >= hi.v {
        return one;
    }
    if d.v <= -hi.v {
        return Dual::constant(0.0);
    }
    if d.v < -lo.v {
        (d + hi) * (d + hi) / (a * b * 2.0)
    } else if d.v <= lo.v {
        d / a + 0.5
    } else {
        one - (hi - d) * (hi - d) / (a * b * 2.0)
    }
}

/// dL/d(coefficients) of W, py and px (in `terms` order) for dL/dPSF = g (size x size).
fn coefficient_adjoints(st: &FastState, gout: &[f64], size: usize) -> [Vec<f64>; 3] {
    let (g, h) = (st.g, size / 2);
    let ncol = h + 1;
    let fft = plan_adjoint::<f32>(g);
    let mut scratch_v = buffer::<f32>(fft.get_inplace_scratch_len());
    let scratch = &mut scratch_v[..fft.get_inplace_scratch_len()];
    // 1. dL/dU on the window's bins: row r of the PSF is bin r - h; pixel h + m and h - m
    //    both come from bin m (fast.rs).
    let mut cols_v = buffer::<f32>(ncol * g);
    let cols = &mut cols_v[..ncol * g];
    zero_fill(cols);
    for r in 0..size {
        let k = if r < h { g - h + r } else { r - h };
        let grow = &gout[r * size..][..size];
        for m in 0..ncol {
            let mut gi = if h + m < size { grow[h + m] } else { 0.0 };
            if m >= 1 {
                gi += grow[h - m];
            }
            let u = st.cols[m * g + k];
            let f = 2.0 * st.scale * gi;
            cols[m * g + k] = Complex32::new((u.re as f64 * f) as f32, (u.im as f64 * f) as f32);
        }
    }
    fft.process_with_scratch(cols, scratch);
    // 2. Row ri's bin m fed column m's entry (k0 + ri) mod g; the other bins fed nothing.
    let k0 = (st.b_lo + g - g / 2) % g;
    let mut rows_v = buffer::<f32>(st.nrow * g);
    let rows = &mut rows_v[..st.nrow * g];
    zero_fill(rows);
    for (ri, row) in rows.chunks_exact_mut(g).enumerate() {
        let k = (k0 + ri) % g;
        for (m, z) in row[..ncol].iter_mut().enumerate() {
            *z = cols[m * g + k];
        }
    }
    fft.process_with_scratch(rows, scratch);
    recycle(scratch_v);
    recycle(cols_v);

    // 3. The cells, row by row (fast.rs's cell values recomputed from the same tables).
    let deg = st.degree;
    let (te, to) = (terms(deg, 0), terms(deg, 1));
    let (tw, ty, tx) = (
        Table::new(&st.w, &te, 0, deg),
        Table::new(&st.py, &te, 0, deg),
        Table::new(&st.px, &to, 1, deg),
    );
    let nq = deg / 2 + 1;
    let sc = st.sc;
    let leg = |x: f64| {
        let (mut p, mut dp) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
        legendre(x, MAX_DEGREE, &mut p, &mut dp);
        (p, dp)
    };
    let pu: Vec<_> = (0..=st.t_hi).map(|t| leg(t as f64 * sc)).collect();
    let (r_in2, r_out2) = ((1.0 - st.delta).max(0.0).powi(2), (1.0 + st.delta).powi(2));
    let half = (g / 2) as f64;
    let (mut adj_w, mut adj_py, mut adj_px) = (vec![0.0; te.len()], vec![0.0; te.len()], vec![0.0; to.len()]);
    for (ri, q) in rows.chunks_exact(g).enumerate() {
        let v = ((st.b_lo + ri) as f64 - half) * sc;
        let n = row_len(st.affine, sc, v, st.t_hi);
        if n == 0 {
            continue;
        }
        let sr = RowSeries::new(&tw, &tx, &ty, v, nq);
        // Per Legendre index i: W's, px's (values and u-slopes; v-slopes) and py's sums.
        let mut acc = [[0.0; MAX_DEGREE + 1]; 5];
        for t in 0..n {
            let u = t as f64 * sc;
            let s = u * u;
            let r2 = series(&sr.r, 2 * nq, s);
            if r2 >= r_out2 {
                continue;
            }
            let jac = series(&sr.j, 2 * nq - 1, s);
            let f = [
                u * series(&sr.x, nq, s),
                series(&sr.y, nq, s),
                series(&sr.xd, nq, s),
                u * series(&sr.xv, nq, s),
                u * series(&sr.yd, nq, s),
                series(&sr.yv, nq, s),
            ];
            let (amp, mut gf) = if r2 <= r_in2 {
                (jac.abs().sqrt(), [0.0; 6])
            } else {
                // amplitude sqrt|J| cov(r, grad r in cells) as a function of the six values
                let x: [Dual<6>; 6] = std::array::from_fn(|k| Dual::variable(f[k], k));
                let [px, py, xu, xv, yu, yv] = x;
                let j = xu * yv - xv * yu;
                let r = (px * px + py * py).sqrt();
                let ir = Dual::constant(sc) / r;
                let cov = cover_dual(r, (px * xu + py * yu) * ir, (px * xv + py * yv) * ir);
                let a = (if j.v < 0.0 { -j } else { j }).sqrt() * cov;
                (a.v, a.d)
            };
            if !(amp > 0.0) {
                continue;
            }
            let z = q[t] + if t > 0 { q[g - t] } else { Complex32::new(0.0, 0.0) };
            let (zr, zi) = (z.re as f64, z.im as f64);
            let (sn, cs) = (2.0 * PI * series(&sr.w, nq, s)).sin_cos();
            let gw = 2.0 * PI * amp * (zi * cs - zr * sn);
            let ga = zr * cs + zi * sn;
            if r2 <= r_in2 {
                // d sqrt|J| = sign(J) dJ / (2 sqrt|J|), J = xu yv - xv yu
                let gj = ga * jac.signum() / (2.0 * amp);
                gf = [0.0, 0.0, gj * f[5], -gj * f[4], -gj * f[3], gj * f[2]];
            } else {
                gf.iter_mut().for_each(|x| *x *= ga);
            }
            let (p, dp) = &pu[t];
            for i in 0..=deg {
                acc[0][i] += gw * p[i];
                acc[1][i] += gf[0] * p[i] + gf[2] * dp[i];
                acc[2][i] += gf[3] * p[i];
                acc[3][i] += gf[1] * p[i] + gf[4] * dp[i];
                acc[4][i] += gf[5] * p[i];
            }
        }
        let (pv, dpv) = leg(v);
        for (k, &(i, j)) in te.iter().enumerate() {
            adj_w[k] += acc[0][i] * pv[j];
            adj_py[k] += acc[3][i] * pv[j] + acc[4][i] * dpv[j];
        }
        for (k, &(i, j)) in to.iter().enumerate() {
            adj_px[k] += acc[1][i] * pv[j] + acc[2][i] * dpv[j];
        }
    }
    recycle(rows_v);
    [adj_w, adj_py, adj_px]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dual_edge_coverage_is_the_coverage_and_its_slope() {
        for &(r, gx, gy) in &[
            (1.001, 0.01, 0.004),
            (0.998, 0.003, 0.009),
            (1.0, 0.007, 0.007),
            (0.9995, 0.01, 0.0001),
            (1.003, 0.006, -0.002),
        ] {
            let x = [r, gx, gy];
            let dual: [Dual<3>; 3] = std::array::from_fn(|k| Dual::variable(x[k], k));
            let c = cover_dual(dual[0], dual[1], dual[2]);
            assert!((c.v - fast::cover_cell(r, gx, gy)).abs() < 1e-14, "{x:?}");
            for k in 0..3 {
                let h = 1e-7 * x[k].abs();
                let (mut a, mut b) = (x, x);
                a[k] += h;
                b[k] -= h;
                let fd = (fast::cover_cell(a[0], a[1], a[2]) - fast::cover_cell(b[0], b[1], b[2])) / (2.0 * h);
                assert!(
                    (fd - c.d[k]).abs() <= 1e-5 * fd.abs().max(1.0),
                    "{x:?} direction {k}: {} vs {fd}",
                    c.d[k]
                );
            }
        }
    }
}
