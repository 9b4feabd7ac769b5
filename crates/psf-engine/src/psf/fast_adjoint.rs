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

/// One row's interior cells (amplitude sqrt|J|) for the reverse pass: their adjoints' moments.
struct Interior<'a> {
    sr: &'a RowSeries,
    s: &'a [f64],
    sc: f64,
    sign: f64,
    amp: &'a [f64],
    w: &'a [f64],
    zr: &'a [f64],
    zi: &'a [f64],
    pw: &'a [Vec<f64>],
}

impl Interior<'_> {
    /// dL/dW and the slopes' adjoints through J per cell (into `f`: W, px_u, px_v u, py_u u,
    /// py_v), then m[k][q] = sum_t f_k s^q.
    fn moments(&self, nq: usize, f: [&mut Vec<f64>; 5], m: &mut [[f64; fast::NL]; 5]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { self.moments_avx2(nq, f, m) };
        }
        self.moments_body(nq, f, m)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn moments_avx2(&self, nq: usize, f: [&mut Vec<f64>; 5], m: &mut [[f64; fast::NL]; 5]) {
        self.moments_body(nq, f, m)
    }

    #[inline(always)]
    fn moments_body(&self, nq: usize, f: [&mut Vec<f64>; 5], m: &mut [[f64; fast::NL]; 5]) {
        match nq {
            5 => self.cells::<5>(f, m),
            6 => self.cells::<6>(f, m),
            _ => self.cells::<7>(f, m),
        }
    }

    #[inline(always)]
    fn cells<const NQ: usize>(&self, f: [&mut Vec<f64>; 5], m: &mut [[f64; fast::NL]; 5]) {
        let n = self.s.len();
        let sr = self.sr;
        let [gw, fxd, fxv, fyd, fyv] = f;
        let (gw, fxd, fxv, fyd, fyv) = (&mut gw[..n], &mut fxd[..n], &mut fxv[..n], &mut fyd[..n], &mut fyv[..n]);
        for t in 0..n {
            let (a, s) = (self.amp[t], self.s[t]);
            let (zr, zi) = (self.zr[t], self.zi[t]);
            let (cs, sn) = fast::cis_turns(self.w[t]);
            gw[t] = 2.0 * PI * a * (zi * cs - zr * sn);
            let ga = zr * cs + zi * sn;
            // d sqrt|J| = sign dJ / (2 sqrt|J|), J = xu yv - xv yu
            let gj = if a > 0.0 {
                ga * self.sign / (2.0 * a.max(1e-300))
            } else {
                0.0
            };
            let u = t as f64 * self.sc;
            let (pxu, pyv) = (fast::horner::<NQ>(&sr.xd, s), fast::horner::<NQ>(&sr.yv, s));
            let (pxv, pyu) = (u * fast::horner::<NQ>(&sr.xv, s), u * fast::horner::<NQ>(&sr.yd, s));
            fxd[t] = gj * pyv;
            fyv[t] = gj * pxu;
            fxv[t] = -gj * pyu * u;
            fyd[t] = -gj * pxv * u;
        }
        for (k, f) in [&*gw, &*fxd, &*fxv, &*fyd, &*fyv].into_iter().enumerate() {
            for (mq, p) in m[k].iter_mut().zip(&self.pw[..NQ]) {
                *mq = dot(f, &p[..n]);
            }
        }
    }
}

/// sum a b in four fixed lanes (vectorizable; the same order every run).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    for (k, (x, y)) in ra.iter().zip(rb).enumerate() {
        acc[k] += x * y;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// Horner in s over the first `n` coefficients.
#[inline]
fn series(c: &[f64], n: usize, s: f64) -> f64 {
    c[..n].iter().rev().fold(0.0, |a, &k| a * s + k)
}

/// `pupil::cover_cell` in dual numbers (the same branches, taken on the values).
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
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { adjoints_avx2(st, gout, size) };
    }
    adjoints_body(st, gout, size)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn adjoints_avx2(st: &FastState, gout: &[f64], size: usize) -> [Vec<f64>; 3] {
    adjoints_body(st, gout, size)
}

#[inline(always)]
fn adjoints_body(st: &FastState, gout: &[f64], size: usize) -> [Vec<f64>; 3] {
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

    // 3. The cells, row by row: fast.rs's cell values from the same tables (vectorized passes
    //    over a row's cells), each cell's dL/dW and dL/d(amplitude), then their moments
    //    sum_t f_t s_t^q (s = u^2) per row, the adjoints of the row's series in s.
    let deg = st.degree;
    let (te, to) = (terms(deg, 0), terms(deg, 1));
    let (tw, ty, tx) = (
        Table::new(&st.w, &te, 0, deg),
        Table::new(&st.py, &te, 0, deg),
        Table::new(&st.px, &to, 1, deg),
    );
    let nq = deg / 2 + 1;
    let sc = st.sc;
    let nt = st.t_hi + 1;
    let s_t: Vec<f64> = (0..nt).map(|t| (t as f64 * sc) * (t as f64 * sc)).collect();
    // s^q at every cell of a row (the same for every row)
    let pw: Vec<Vec<f64>> = (0..nq)
        .map(|q| s_t.iter().map(|s| s.powi(q as i32)).collect())
        .collect();
    let (r_in2, r_out2) = ((1.0 - st.delta).max(0.0).powi(2), (1.0 + st.delta).powi(2));
    let half = (g / 2) as f64;
    let leg = fast::legendre_monomials();
    let (mut adj_w, mut adj_py, mut adj_px) = (vec![0.0; te.len()], vec![0.0; te.len()], vec![0.0; to.len()]);
    let z = || vec![0.0; nt];
    let (mut w, mut amp, mut jac, mut r2, mut jin) = (z(), z(), z(), z(), z());
    let (mut gw, mut fxd, mut fxv, mut fyd, mut fyv) = (z(), z(), z(), z(), z());
    let (mut zr, mut zi) = (z(), z());
    for (ri, q) in rows.chunks_exact(g).enumerate() {
        let v = ((st.b_lo + ri) as f64 - half) * sc;
        let n = row_len(st.affine, sc, v, st.t_hi);
        if n == 0 {
            continue;
        }
        let sr = RowSeries::new(&tw, &tx, &ty, v, nq);
        let s = &s_t[..n];
        match nq {
            5 => fast::cells::<5, 9, 10>(&sr, s, r_in2, &mut w, &mut amp, &mut jac, &mut r2, &mut jin),
            6 => fast::cells::<6, 11, 12>(&sr, s, r_in2, &mut w, &mut amp, &mut jac, &mut r2, &mut jin),
            _ => fast::cells::<7, 13, 14>(&sr, s, r_in2, &mut w, &mut amp, &mut jac, &mut r2, &mut jin),
        }
        // The Jacobian's sign (one over the pupil: a fold is refused upstream).
        let sign = if sr.j[0] < 0.0 { -1.0 } else { 1.0 };
        let (xd, xv, yd, yv) = (&sr.xd[..nq], &sr.xv[..nq], &sr.yd[..nq], &sr.yv[..nq]);
        // Each cell's adjoint, its mirror image's added.
        zr[0] = q[0].re as f64;
        zi[0] = q[0].im as f64;
        for t in 1..n {
            zr[t] = (q[t].re + q[g - t].re) as f64;
            zi[t] = (q[t].im + q[g - t].im) as f64;
        }
        let mut m = [[0.0; fast::NL]; 5];
        let io = Interior {
            sr: &sr,
            s,
            sc,
            sign,
            amp: &amp[..n],
            w: &w[..n],
            zr: &zr[..n],
            zi: &zi[..n],
            pw: &pw,
        };
        io.moments(nq, [&mut gw, &mut fxd, &mut fxv, &mut fyd, &mut fyv], &mut m);
        // The rim cells (partly covered: amplitude sqrt|J| cov), one by one, in dual numbers.
        let (mut mx1, mut my0) = ([0.0; fast::NL], [0.0; fast::NL]);
        for t in 0..n {
            if !(r2[t] > r_in2 && r2[t] < r_out2) {
                continue;
            }
            let (st_, u) = (s[t], t as f64 * sc);
            let f = [
                u * series(&sr.x, nq, st_),
                series(&sr.y, nq, st_),
                series(xd, nq, st_),
                u * series(xv, nq, st_),
                u * series(yd, nq, st_),
                series(yv, nq, st_),
            ];
            let x: [Dual<6>; 6] = std::array::from_fn(|k| Dual::variable(f[k], k));
            let [px, py, xu, xvd, yu, yvd] = x;
            let j = xu * yvd - xvd * yu;
            let r = (px * px + py * py).sqrt();
            let ir = Dual::constant(sc) / r;
            let cov = cover_dual(r, (px * xu + py * yu) * ir, (px * xvd + py * yvd) * ir);
            let a = (if j.v < 0.0 { -j } else { j }).sqrt() * cov;
            if !(a.v > 0.0) {
                continue;
            }
            let (zrt, zit) = (zr[t], zi[t]);
            let (cs, sn) = fast::cis_turns(w[t]);
            let gwt = 2.0 * PI * a.v * (zit * cs - zrt * sn);
            let gf = a.d.map(|d| d * (zrt * cs + zit * sn));
            let mut p = 1.0;
            for k in 0..nq {
                m[0][k] += gwt * p;
                mx1[k] += gf[0] * u * p;
                m[1][k] += gf[2] * p;
                m[2][k] += gf[3] * u * p;
                my0[k] += gf[1] * p;
                m[3][k] += gf[4] * u * p;
                m[4][k] += gf[5] * p;
                p *= st_;
            }
        }
        // Adjoints of the row's series: W = sum w_q s^q; px = u sum x_q s^q, px_u = sum (2q + 1)
        // x_q s^q, px_v = u sum x'_q s^q; py = sum y_q s^q, py_u = u sum 2q y_q s^(q - 1),
        // py_v = sum y'_q s^q (' = d/dv; RowSeries).
        let mut gx = [0.0; fast::NL];
        let mut gy = [0.0; fast::NL];
        for k in 0..nq {
            gx[k] = mx1[k] + (2 * k + 1) as f64 * m[1][k];
            gy[k] = my0[k] + if k > 0 { 2.0 * k as f64 * m[3][k - 1] } else { 0.0 };
        }
        // A row's series coefficient q of parity p is sum_ij c_ij leg[i][2q + p] P_j(v), its
        // v-derivative's the same with P'_j(v) (Table::new).
        let (mut pv, mut dpv) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
        legendre(v, MAX_DEGREE, &mut pv, &mut dpv);
        let along = |gq: &[f64], i: usize, parity: usize| -> f64 {
            (0..nq)
                .filter(|&k| 2 * k + parity <= i)
                .map(|k| gq[k] * leg[i][2 * k + parity])
                .sum()
        };
        for (k, &(i, j)) in te.iter().enumerate() {
            adj_w[k] += along(&m[0], i, 0) * pv[j];
            adj_py[k] += along(&gy, i, 0) * pv[j] + along(&m[4], i, 0) * dpv[j];
        }
        for (k, &(i, j)) in to.iter().enumerate() {
            adj_px[k] += along(&gx, i, 1) * pv[j] + along(&m[2], i, 1) * dpv[j];
        }
    }
    recycle(rows_v);
    [adj_w, adj_py, adj_px]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::pupil;

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
            assert!((c.v - pupil::cover_cell(r, gx, gy)).abs() < 1e-14, "{x:?}");
            for k in 0..3 {
                let h = 1e-7 * x[k].abs();
                let (mut a, mut b) = (x, x);
                a[k] += h;
                b[k] -= h;
                let fd = (pupil::cover_cell(a[0], a[1], a[2]) - pupil::cover_cell(b[0], b[1], b[2])) / (2.0 * h);
                assert!(
                    (fd - c.d[k]).abs() <= 1e-5 * fd.abs().max(1.0),
                    "{x:?} direction {k}: {} vs {fd}",
                    c.d[k]
                );
            }
        }
    }
}
