//! The fast FFT PSF (the dataset path): the pupil function resampled onto a grid of
//! image-space direction cosines whose FFT lands directly on the output pixels.
//!
//! The image-plane field is a Fourier transform over the direction cosines (fft.rs):
//!
//!   U(x, y) = (n/lambda) int A(L, M) exp(i 2 pi W) exp(i k n (L x + M y)) dL dM.
//!
//! fft.rs samples the pupil on a square grid of entrance-pupil coordinates, where (L, M)
//! is only approximately affine (a Taylor series per extra order of distortion) and the
//! native pitch is whatever the pupil gives (then resampled); each sample is a traced ray.
//! Here instead:
//!
//! 1. A coarse set of real rays (half the pupil: for a field along y the other half is its
//!    mirror image; plus rays on the rim) gives px, py (entrance-pupil coordinates) and W
//!    (waves against the reference sphere) at their (L, M).
//! 2. Least-squares polynomials px(L, M), py(L, M), W(L, M) in a Legendre basis, odd (px)
//!    or even (py, W) in L. The degree is the lowest of `DEGREES` whose largest residual at
//!    the rays is within `W_TOL_WAVES` (W) and `P_TOL` (px, py); none: not applicable.
//! 3. The pupil function on the grid L = (a - g/2) dL, M = M_chief + (b - g/2) dL with
//!    dL = lambda / (n g pixel), so that the FFT's native pitch is the output pixel (no
//!    resampling). Amplitude sqrt(|d(px, py)/d(L, M)|) (flux is uniform over the entrance
//!    pupil with paraxial aiming), and each rim cell weighted by the fraction of its area
//!    inside the pupil edge (an anti-aliased edge: its quadrature converges far faster than
//!    a 0/1 mask's).
//! 4. Row transforms over the occupied rows, column transforms over the columns x >= 0
//!    only (the intensity is even in x), in single precision like fft.rs.
//!
//! The grid g is the smallest fast FFT size whose field P holds twice the window, and
//! twice the geometric spot's extent plus the window (light from a ray at x wraps around to
//! x - P, outside the window), with at least `pupil_samples` grid cells across the pupil.
//!
//! It applies to the FFT method with paraxial aiming, point sampling and no fixed
//! fft_grid, where every ray of the coarse set reaches the image (no vignetting, no TIR)
//! and the fits hold; otherwise `fast_psf` says why and the caller runs fft.rs.

use super::fft::{buffer, octant, plan, quarter_turns, recycle, report_grid, zero_fill};
use super::{Diagnostics, Method, PsfOptions};
use crate::aim::{Aiming, Beam};
use crate::error::Result;
use crate::psf::pupil::{back_to_sphere, cover_cell, half_pupil, reference, Reference};
use crate::trace::System;
use glam::DVec3;
use num_complex::Complex32;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// Traced grid across the pupil diameter (the half px > 0 is traced) and rays on the half
/// rim, at a radius just inside the unit circle: a clear aperture that meets the beam's
/// edge exactly (a stop sized to the paraxial marginal ray, at another wavelength) clips a
/// sliver thinner than 1 - R_RIM, of no consequence at this tolerance, and such a design
/// keeps the fast path. Where the rim rays pass, every polar-grid ray of the relative
/// illumination (outer ring at 0.979) passes too.
pub(crate) const NT: usize = 12;
pub(crate) const N_RIM: usize = 25;
pub(crate) const R_RIM: f64 = 0.999;
/// Polynomial degrees tried, in order.
const DEGREES: [usize; 3] = [8, 10, 12];
pub(crate) const MAX_DEGREE: usize = 12;
/// Largest fit residual accepted at the traced rays: wavefront (waves) and pupil coordinates.
pub const W_TOL_WAVES: f64 = 1e-3;
pub const P_TOL: f64 = 1e-4;
pub(crate) const MAX_GRID: usize = 8192;
/// Where the fast path does not apply, the general FFT takes over at most at these pupil
/// samples (mod.rs).
pub(crate) const FALLBACK_SAMPLES: usize = 256;
/// How a refusal of that general FFT names the fast path's reason (auto reads it).
pub(crate) const FELL_BACK: &str = "the fast path had fallen back: ";

/// Whether the fast path's reason to fall back lies in the pupil (its fits, the traced
/// pupil's area, the coarse rays), which no sampling changes, rather than in the grid that
/// this sampling asked for.
pub(crate) fn fallback_is_the_pupils(why: &str) -> bool {
    !(why.contains("grid would exceed") || why.contains("does not fit in the direction grid"))
}
/// Cells are evaluated out to this radius of the affine approximation of the pupil map
/// (its distortion is far smaller: within 1% at the paper-triplet's corner; a cut pupil
/// fails the area test and falls back).
const GUARD: f64 = 1.05;

/// Cells t = 0..n of the grid row at v: those within GUARD pupil radii of the affine map
/// `aff` = (pxu, py0, pyv) (x grows with t), at most t_hi + 1; 0 where the row misses it.
pub(super) fn row_len(aff: (f64, f64, f64), sc: f64, v: f64, t_hi: usize) -> usize {
    let (pxu, py0, pyv) = aff;
    let pya = py0 + pyv * v;
    let room = GUARD * GUARD - pya * pya;
    if room <= 0.0 {
        return 0;
    }
    ((room.sqrt() / (pxu.abs() * sc)).floor() as usize + 1).min(t_hi + 1)
}
/// The grid's pupil area (sum of cell areas times edge coverage) must match the unit
/// circle's to this fraction, else the fit is not trusted.
const AREA_TOL: f64 = 1e-3;

/// What the reverse pass of a fitted-pupil fast PSF (psf/fast_adjoint.rs) takes from its
/// forward pass: the fits, the grid, and the transformed field U (columns m = 0..=h, each of
/// g bins).
pub(crate) struct FastState {
    pub(crate) degree: usize,
    /// Coefficients in `terms` order: W and py (even in u), px (odd).
    pub(crate) w: Vec<f64>,
    pub(crate) py: Vec<f64>,
    pub(crate) px: Vec<f64>,
    /// The affine pupil map (pxu, py0, pyv) that bounds each row's cells.
    pub(crate) affine: (f64, f64, f64),
    pub(crate) g: usize,
    pub(crate) b_lo: usize,
    pub(crate) nrow: usize,
    pub(crate) t_hi: usize,
    /// Cell size in u, v; the rim zone's half width; intensity per |U|^2.
    pub(crate) sc: f64,
    pub(crate) delta: f64,
    pub(crate) scale: f64,
    /// The field: ncol x g values from index 0 (a pooled buffer; recycle it).
    pub(crate) cols: Vec<Complex32>,
}

/// Whether the fast path is asked for and can apply to these options.
pub fn applies(o: &PsfOptions) -> bool {
    o.fast && o.method == Method::Fft && o.aiming == Aiming::Paraxial && !o.integrate && o.fft_grid.is_none()
}

struct Samples {
    px: Vec<f64>,
    py: Vec<f64>,
}

/// Cell centres of the NT x NT grid with px > 0 inside the unit circle, then the half rim.
fn samples() -> &'static Samples {
    static S: OnceLock<Samples> = OnceLock::new();
    S.get_or_init(|| {
        let (px, py) = half_pupil(NT, N_RIM, R_RIM);
        Samples { px, py }
    })
}

/// Legendre polynomials P_0..=P_deg at x, and their derivatives.
#[inline]
pub(crate) fn legendre(x: f64, deg: usize, p: &mut [f64], dp: &mut [f64]) {
    p[0] = 1.0;
    dp[0] = 0.0;
    if deg >= 1 {
        p[1] = x;
        dp[1] = 1.0;
    }
    for n in 1..deg {
        let nf = n as f64;
        p[n + 1] = ((2.0 * nf + 1.0) * x * p[n] - nf * p[n - 1]) / (nf + 1.0);
        dp[n + 1] = dp[n - 1] + (2.0 * nf + 1.0) * p[n];
    }
}

/// Monomial coefficients of the Legendre polynomials: LEG[i][k] = coefficient of x^k in P_i.
pub(super) fn legendre_monomials() -> &'static [[f64; MAX_DEGREE + 1]; MAX_DEGREE + 1] {
    static T: OnceLock<[[f64; MAX_DEGREE + 1]; MAX_DEGREE + 1]> = OnceLock::new();
    T.get_or_init(|| {
        let mut t = [[0.0; MAX_DEGREE + 1]; MAX_DEGREE + 1];
        t[0][0] = 1.0;
        t[1][1] = 1.0;
        for n in 1..MAX_DEGREE {
            let nf = n as f64;
            for k in 0..=MAX_DEGREE {
                let up = if k > 0 { t[n][k - 1] } else { 0.0 };
                t[n + 1][k] = ((2.0 * nf + 1.0) * up - nf * t[n - 1][k]) / (nf + 1.0);
            }
        }
        t
    })
}

/// Terms (i, j) of P_i(u) P_j(v) with i + j <= deg and i of the given parity.
pub(crate) fn terms(deg: usize, parity: usize) -> Vec<(usize, usize)> {
    (parity..=deg)
        .step_by(2)
        .flat_map(|i| (0..=deg - i).map(move |j| (i, j)))
        .collect()
}

/// P_0..=P_MAX_DEGREE at one point.
pub(crate) type Leg = [f64; MAX_DEGREE + 1];

/// Legendre values at each of `x`.
pub(crate) fn legendre_table(x: &[f64]) -> Vec<Leg> {
    let mut d = [0.0; MAX_DEGREE + 1];
    x.iter()
        .map(|&x| {
            let mut p = [0.0; MAX_DEGREE + 1];
            legendre(x, MAX_DEGREE, &mut p, &mut d);
            p
        })
        .collect()
}

/// Least squares of each of `ys` on the terms at the points (u, v) (their Legendre values
/// `pu`, `pv`), by the normal equations (well conditioned in this basis) and Cholesky. Returns the coefficients per
/// function and the largest |residual| per function; None if the system is singular.
pub(crate) fn lsq(pu: &[Leg], pv: &[Leg], ys: &[&[f64]], tm: &[(usize, usize)]) -> Option<(Vec<Vec<f64>>, Vec<f64>)> {
    let (t, m, nf) = (tm.len(), pu.len(), ys.len());
    // Basis matrix phi (m x t, row-major) and the values (m x nf).
    let mut phi = vec![0.0; m * t];
    for (row, (pu, pv)) in phi.chunks_exact_mut(t).zip(pu.iter().zip(pv)) {
        for (f, &(i, j)) in row.iter_mut().zip(tm) {
            *f = pu[i] * pv[j];
        }
    }
    let mut y = vec![0.0; m * nf];
    for (k, row) in y.chunks_exact_mut(nf).enumerate() {
        for (yv, ys) in row.iter_mut().zip(ys) {
            *yv = ys[k];
        }
    }
    // G = phi^T phi (t x t), rhs = phi^T y (t x nf).
    let (mut g, mut rhs) = (vec![0.0; t * t], vec![0.0; t * nf]);
    // SAFETY: the pointers and strides describe the row-major arrays above, in bounds.
    unsafe {
        matrixmultiply::dgemm(
            t,
            m,
            t,
            1.0,
            phi.as_ptr(),
            1,
            t as isize,
            phi.as_ptr(),
            t as isize,
            1,
            0.0,
            g.as_mut_ptr(),
            t as isize,
            1,
        );
        matrixmultiply::dgemm(
            t,
            m,
            nf,
            1.0,
            phi.as_ptr(),
            1,
            t as isize,
            y.as_ptr(),
            nf as isize,
            1,
            0.0,
            rhs.as_mut_ptr(),
            nf as isize,
            1,
        );
    }
    if !cholesky(&mut g, t) {
        return None;
    }
    let mut coef = vec![0.0; t * nf];
    for f in 0..nf {
        let mut x: Vec<f64> = (0..t).map(|r| rhs[r * nf + f]).collect();
        cholesky_solve(&g, t, &mut x);
        for (r, xv) in x.into_iter().enumerate() {
            coef[r * nf + f] = xv;
        }
    }
    // Residuals: phi coef - y.
    let mut fitted = vec![0.0; m * nf];
    // SAFETY: as above.
    unsafe {
        matrixmultiply::dgemm(
            m,
            t,
            nf,
            1.0,
            phi.as_ptr(),
            t as isize,
            1,
            coef.as_ptr(),
            nf as isize,
            1,
            0.0,
            fitted.as_mut_ptr(),
            nf as isize,
            1,
        );
    }
    let worst = (0..nf)
        .map(|f| {
            fitted
                .iter()
                .zip(&y)
                .skip(f)
                .step_by(nf)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        })
        .collect();
    let coefs = (0..nf).map(|f| (0..t).map(|r| coef[r * nf + f]).collect()).collect();
    Some((coefs, worst))
}

/// Cholesky G = L L^T of a symmetric t x t matrix (row-major), L into the lower triangle in
/// place; false where G is not positive definite to working precision.
pub(crate) fn cholesky(g: &mut [f64], t: usize) -> bool {
    for c in 0..t {
        let mut d = g[c * t + c];
        for k in 0..c {
            d -= g[c * t + k] * g[c * t + k];
        }
        if !(d > 1e-14 * g[c * t + c].max(1e-300)) {
            return false;
        }
        let d = d.sqrt();
        g[c * t + c] = d;
        for r in c + 1..t {
            let mut s = g[r * t + c];
            for k in 0..c {
                s -= g[r * t + k] * g[c * t + k];
            }
            g[r * t + c] = s / d;
        }
    }
    true
}

/// Solves L L^T x = b in place (L from `cholesky`).
pub(crate) fn cholesky_solve(l: &[f64], t: usize, x: &mut [f64]) {
    for r in 0..t {
        let mut s = x[r];
        for k in 0..r {
            s -= l[r * t + k] * x[k];
        }
        x[r] = s / l[r * t + r];
    }
    for r in (0..t).rev() {
        let mut s = x[r];
        for k in r + 1..t {
            s -= l[k * t + r] * x[k];
        }
        x[r] = s / l[r * t + r];
    }
}

/// Lanes of the per-row series in s = u^2 (at most MAX_DEGREE / 2 + 1 terms used).
pub(super) const NL: usize = 8;
pub(super) type Lanes = [f64; NL];

/// A fitted function f(u, v) = sum c_ij P_i(u) P_j(v) of one parity in u, as monomials:
/// f = u^parity sum_q s^q sum_k t[k][q] v^k (s = u^2), and df/dv from `dt`.
pub(super) struct Table {
    t: [Lanes; MAX_DEGREE + 1],
    dt: [Lanes; MAX_DEGREE + 1],
    deg: usize,
}

impl Table {
    pub(super) fn new(c: &[f64], tm: &[(usize, usize)], parity: usize, deg: usize) -> Table {
        let leg = legendre_monomials();
        let mut t = [[0.0; NL]; MAX_DEGREE + 1];
        for (&c, &(i, j)) in c.iter().zip(tm) {
            for k in (parity..=i).step_by(2) {
                let a = c * leg[i][k];
                let q = (k - parity) / 2;
                for (kk, tk) in t.iter_mut().enumerate().take(j + 1) {
                    tk[q] += a * leg[j][kk];
                }
            }
        }
        let mut dt = [[0.0; NL]; MAX_DEGREE + 1];
        for k in 0..deg {
            for q in 0..NL {
                dt[k][q] = (k + 1) as f64 * t[k + 1][q];
            }
        }
        Table { t, dt, deg }
    }

    /// The row at v: f(., v) = u^parity sum_q val[q] s^q.
    #[inline(always)]
    fn val(&self, v: f64) -> Lanes {
        horner_lanes(&self.t[..=self.deg], v)
    }

    /// df/dv(., v) = u^parity sum_q dv[q] s^q.
    #[inline(always)]
    fn dv(&self, v: f64) -> Lanes {
        horner_lanes(&self.dt[..self.deg.max(1)], v)
    }
}

#[inline(always)]
fn horner_lanes(t: &[Lanes], v: f64) -> Lanes {
    let mut a = [0.0; NL];
    for tk in t.iter().rev() {
        for q in 0..NL {
            a[q] = a[q] * v + tk[q];
        }
    }
    a
}

/// The direction grid (before rounding to `fast_len`) for `cells` grid cells across a
/// pupil `dir_extent` wide in direction cosines, a spot reaching `spot_mm` from the chief
/// ray, and the output window: half the FFT field covers the spot plus half the window
/// (light from a ray at x wraps to x - P, outside the window), and the field is at least
/// twice the window. (Less, e.g. P = 4 x 70 um for a 128 um window, costs accuracy: 1.2%
/// L1 in the tests' defocused design.)
pub(crate) fn grid_want(cells: usize, wl_mm: f64, n_img: f64, dir_extent: f64, spot_mm: f64, o: &PsfOptions) -> f64 {
    let want_samples = cells as f64 * wl_mm / (n_img * o.pixel_mm * dir_extent);
    let want_spot = 2.0 * spot_mm / o.pixel_mm + o.size as f64;
    want_samples.max(want_spot).max((2 * o.size) as f64).ceil()
}

/// Smallest FFT size 2^k or 3 * 2^k (k >= 1) at least n.
pub(crate) fn fast_len(n: usize) -> usize {
    let p = n.max(2).next_power_of_two();
    if p / 4 * 3 >= n && p / 4 * 3 >= 2 {
        p / 4 * 3
    } else {
        p
    }
}

/// One row's series in s = u^2 (u >= 0): W = W(s); px = u X(s), d px/du = XD(s),
/// d px/dv = u XV(s); py = Y(s), d py/du = u YD(s), d py/dv = YV(s); and the products
/// J = XD YV - s XV YD (the Jacobian d(px, py)/d(u, v)) and R = s X^2 + Y^2 (r^2).
/// `nq` terms in W, X, Y, ...; 2 nq - 1 in J, 2 nq in R.
pub(super) struct RowSeries {
    pub(super) w: Lanes,
    pub(super) x: Lanes,
    pub(super) xd: Lanes,
    pub(super) xv: Lanes,
    pub(super) y: Lanes,
    pub(super) yd: Lanes,
    pub(super) yv: Lanes,
    pub(super) j: [f64; 2 * NL],
    pub(super) r: [f64; 2 * NL],
}

impl RowSeries {
    #[inline(always)]
    pub(super) fn new(tw: &Table, tx: &Table, ty: &Table, v: f64, nq: usize) -> RowSeries {
        let (w, x, xv, y, yv) = (tw.val(v), tx.val(v), tx.dv(v), ty.val(v), ty.dv(v));
        let (mut xd, mut yd) = ([0.0; NL], [0.0; NL]);
        for q in 0..nq {
            xd[q] = (2 * q + 1) as f64 * x[q];
            if q + 1 < nq {
                yd[q] = 2.0 * (q + 1) as f64 * y[q + 1];
            }
        }
        let (mut j, mut r) = ([0.0; 2 * NL], [0.0; 2 * NL]);
        for a in 0..nq {
            for b in 0..nq {
                j[a + b] += xd[a] * yv[b];
                j[a + b + 1] -= xv[a] * yd[b];
                r[a + b + 1] += x[a] * x[b];
                r[a + b] += y[a] * y[b];
            }
        }
        RowSeries {
            w,
            x,
            xd,
            xv,
            y,
            yd,
            yv,
            j,
            r,
        }
    }
}

/// Per-cell work arrays of one row, reused from row to row (and PSF to PSF on a thread).
#[derive(Default)]
struct CellWork {
    /// s = u^2 of cells t = 0..: the same for every row of a PSF.
    s: Vec<f64>,
    w: Vec<f64>,
    amp: Vec<f64>,
    jac: Vec<f64>,
    r2: Vec<f64>,
    jin: Vec<f64>,
    /// Output rows of one tile.
    tile: Vec<f64>,
}

#[inline(always)]
pub(super) fn horner<const L: usize>(c: &[f64], x: f64) -> f64 {
    let c: &[f64; L] = c[..L].try_into().unwrap();
    let mut a = c[L - 1];
    for k in (0..L - 1).rev() {
        a = a * x + c[k];
    }
    a
}

/// W, |J|, r^2, the interior amplitude sqrt|J| and area |J| of cells 0..n (one pass,
/// vectorized across the cells).
#[inline(always)]
pub(super) fn cells<const NQ: usize, const NJ: usize, const NR: usize>(
    sr: &RowSeries,
    s: &[f64],
    r_in2: f64,
    w: &mut [f64],
    amp: &mut [f64],
    jac: &mut [f64],
    r2: &mut [f64],
    jin: &mut [f64],
) {
    let n = s.len();
    let (w, amp, jac, r2, jin) = (&mut w[..n], &mut amp[..n], &mut jac[..n], &mut r2[..n], &mut jin[..n]);
    for i in 0..n {
        let x = s[i];
        let wv = horner::<NQ>(&sr.w, x);
        let j = horner::<NJ>(&sr.j, x).abs();
        let rr = horner::<NR>(&sr.r, x);
        let inside = if rr <= r_in2 { 1.0 } else { 0.0 };
        w[i] = wv;
        jac[i] = j;
        r2[i] = rr;
        amp[i] = j.sqrt() * inside;
        jin[i] = j * inside;
    }
}

/// The partly covered cells of a row (r^2 within (r_in2, r_out2)): their amplitude, and
/// their area, energy and amplitude sums (mirror images included).
#[inline(always)]
fn rim<const NQ: usize>(
    cw: &mut CellWork,
    sr: &RowSeries,
    n: usize,
    sc: f64,
    r_in2: f64,
    r_out2: f64,
) -> (f64, f64, f64) {
    let (mut area, mut energy, mut amp_sum) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let (r2, jac) = (cw.r2[i], cw.jac[i]);
        if r2 > r_in2 && r2 < r_out2 {
            let mult = if i == 0 { 1.0 } else { 2.0 };
            let (s, u) = (cw.s[i], i as f64 * sc);
            let px = u * horner::<NQ>(&sr.x, s);
            let py = horner::<NQ>(&sr.y, s);
            let (xu, xv) = (horner::<NQ>(&sr.xd, s), u * horner::<NQ>(&sr.xv, s));
            let (yu, yv) = (u * horner::<NQ>(&sr.yd, s), horner::<NQ>(&sr.yv, s));
            let r = r2.sqrt();
            let ir = sc / r.max(1e-300);
            let cov = cover_cell(r, (px * xu + py * yu) * ir, (px * xv + py * yv) * ir);
            let amp = jac.sqrt() * cov;
            cw.amp[i] = amp;
            area += mult * jac * cov;
            energy += mult * jac * cov * cov;
            amp_sum += mult * amp;
        }
    }
    (area, energy, amp_sum)
}

#[inline(always)]
fn row_body(
    cw: &mut CellWork,
    row: &mut [Complex32],
    tab: [&Table; 3],
    v: f64,
    nq: usize,
    n: usize,
    sc: f64,
    delta: f64,
) -> (f64, f64, f64) {
    let sr = &RowSeries::new(tab[0], tab[1], tab[2], v, nq);
    for v in [&mut cw.w, &mut cw.amp, &mut cw.jac, &mut cw.r2, &mut cw.jin] {
        if v.len() < n {
            v.resize(n, 0.0);
        }
    }
    // Cells well inside the edge (r <= 1 - delta) are fully covered, cells beyond 1 + delta
    // empty: one branch-free pass, then the few rim cells one by one.
    let (r_in2, r_out2) = ((1.0 - delta).max(0.0).powi(2), (1.0 + delta).powi(2));
    {
        let CellWork {
            s,
            w,
            amp,
            jac,
            r2,
            jin,
            ..
        } = &mut *cw;
        let s = &s[..n];
        match nq {
            5 => cells::<5, 9, 10>(sr, s, r_in2, w, amp, jac, r2, jin),
            6 => cells::<6, 11, 12>(sr, s, r_in2, w, amp, jac, r2, jin),
            _ => cells::<7, 13, 14>(sr, s, r_in2, w, amp, jac, r2, jin),
        }
    }
    // Interior sums in four fixed lanes (vectorizable, same order every run); the first
    // cell (t = 0) counts once, the others twice (their mirror images).
    let lanes = |v: &[f64]| -> f64 {
        let (mut a0, mut a1, mut a2, mut a3) = (0.0, 0.0, 0.0, 0.0);
        let mut it = v.chunks_exact(4);
        for c in &mut it {
            a0 += c[0];
            a1 += c[1];
            a2 += c[2];
            a3 += c[3];
        }
        let mut acc = [a0, a1, a2, a3];
        for (a, x) in acc.iter_mut().zip(it.remainder()) {
            *a += x;
        }
        (acc[0] + acc[1]) + (acc[2] + acc[3])
    };
    let (a_in, m_in) = (
        2.0 * lanes(&cw.jin[..n]) - cw.jin[0],
        2.0 * lanes(&cw.amp[..n]) - cw.amp[0],
    );
    let (mut area, mut amp_sum, mut energy) = (a_in, m_in, a_in);
    // The rim cells one by one.
    let (a, e, m) = match nq {
        5 => rim::<5>(cw, sr, n, sc, r_in2, r_out2),
        6 => rim::<6>(cw, sr, n, sc, r_in2, r_out2),
        _ => rim::<7>(cw, sr, n, sc, r_in2, r_out2),
    };
    area += a;
    energy += e;
    amp_sum += m;
    // Phasors up to the last cell inside (zeros beyond), in single precision, and their
    // mirror images g - t; zeros between.
    let m = cw.amp[..n].iter().rposition(|&a| a > 0.0).map_or(0, |i| i + 1);
    let g = row.len();
    let (head, tail) = row.split_at_mut(n);
    for ((o, &t), &a) in head[..m].iter_mut().zip(&cw.w[..m]).zip(&cw.amp[..m]) {
        let (c, s) = cis_turns(t);
        *o = if a > 0.0 {
            Complex32::new((a * c) as f32, (a * s) as f32)
        } else {
            Complex32::new(0.0, 0.0)
        };
    }
    zero_fill(&mut head[m..]);
    let tl = tail.len();
    zero_fill(&mut tail[..g + 1 - 2 * n]);
    for (o, z) in tail[tl + 1 - n..].iter_mut().rev().zip(&head[1..]) {
        *o = *z;
    }
    (area * sc * sc, amp_sum, energy * sc * sc)
}

/// (cos, sin)(2 pi t) for t in turns: reduction to an octant and near-minimax polynomials
/// in th^2 of six terms each on |th| <= pi/4 (error below 1e-13, far below the
/// single-precision field's rounding), branch free so that loops over it vectorize.
#[inline(always)]
pub(super) fn cis_turns(t: f64) -> (f64, f64) {
    let (q, th) = octant(t);
    let x2 = th * th;
    // sin(th) / th and cos(th) fitted in x2 on [0, (pi/4)^2] (errors 6e-15 and 6e-14).
    const S: [f64; 6] = [
        0.9999999999999961,
        -0.16666666666617147,
        0.008333333323944567,
        -0.00019841263326625605,
        2.7555276987761723e-06,
        -2.475688510829627e-08,
    ];
    const C: [f64; 6] = [
        0.999999999999938,
        -0.4999999999934691,
        0.04166666654360046,
        -0.0013888880383500714,
        2.479892728171647e-05,
        -2.7173353223481015e-07,
    ];
    let s = th * S.iter().rev().fold(0.0, |acc, &c| acc * x2 + c);
    let c = C.iter().rev().fold(0.0, |acc, &c| acc * x2 + c);
    quarter_turns(q, c, s)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn row_avx2(
    cw: &mut CellWork,
    row: &mut [Complex32],
    tab: [&Table; 3],
    v: f64,
    nq: usize,
    n: usize,
    sc: f64,
    delta: f64,
) -> (f64, f64, f64) {
    row_body(cw, row, tab, v, nq, n, sc, delta)
}

impl CellWork {
    /// The pupil field of cells t = 0..n of a row and their mirror images, into `row`;
    /// returns the row's pupil area, amplitude sum and energy, mirrored cells included.
    /// `delta`: bound on the change of the pupil radius over one cell (the edge zone).
    /// `tab`: the tables of W, px and py; `v` the row.
    fn row(
        &mut self,
        row: &mut [Complex32],
        tab: [&Table; 3],
        v: f64,
        nq: usize,
        n: usize,
        sc: f64,
        delta: f64,
    ) -> (f64, f64, f64) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { row_avx2(self, row, tab, v, nq, n, sc, delta) };
        }
        row_body(self, row, tab, v, nq, n, sc, delta)
    }
}

thread_local! {
    /// The per-cell work arrays, kept between calls on this thread.
    static CELL_WORK: std::cell::RefCell<CellWork> = std::cell::RefCell::new(CellWork::default());
    /// f64 buffers kept between calls on this thread (window-sized buffers are at the
    /// allocator's mmap threshold: fresh pages, faulted in and zeroed, on every call).
    static F64_POOL: std::cell::RefCell<Vec<Vec<f64>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// A buffer of `len` values with unspecified contents (every one is written by the caller).
fn take_f64(len: usize) -> Vec<f64> {
    let mut v = F64_POOL.with(|p| p.borrow_mut().pop()).unwrap_or_default();
    v.resize(len, 0.0);
    v
}

/// Hands a buffer back to this thread's pool (e.g. a fast PSF's data, once consumed).
pub fn give_f64(v: Vec<f64>) {
    F64_POOL.with(|p| {
        let mut p = p.borrow_mut();
        if p.len() < 4 {
            p.push(v);
        }
    });
}

/// Whether every ray of the coarse set (half pupil and rim) reaches the image for the
/// on-axis beam at this system's wavelength: then the axial flux is the full launched flux.
pub fn axis_clear(sys: &System) -> Result<bool> {
    let beam = Beam::new(sys, 0.0, Aiming::Paraxial)?;
    let s = samples();
    let t = beam.trace_pupil_soa(&s.px, &s.py);
    Ok(t.status.iter().all(|&c| c == 0))
}

/// The fast PSF: Ok(Ok(data)) with `d` filled, or Ok(Err(reason)) where it does not apply
/// (the caller then runs fft.rs). Engine errors (the chief ray fails, ...) are errors.
pub fn fast_psf(
    sys: &System,
    field_deg: f64,
    o: &PsfOptions,
    d: &mut Diagnostics,
) -> Result<std::result::Result<Vec<f64>, &'static str>> {
    fast_psf_pupil(sys, field_deg, o, d, false)
}

/// `fast_psf`, with the pupil traced cell by cell (psf/traced.rs) where `traced` is true even
/// if the polynomial fits hold (for tests: the two ways to the same pupil must agree).
pub(crate) fn fast_psf_pupil(
    sys: &System,
    field_deg: f64,
    o: &PsfOptions,
    d: &mut Diagnostics,
    force_traced: bool,
) -> Result<std::result::Result<Vec<f64>, &'static str>> {
    fast_psf_kept(sys, field_deg, o, d, force_traced, None)
}

/// `fast_psf_pupil`, and where `keep` is given and the fits held, what the reverse pass needs
/// into it (None after a traced pupil).
pub(crate) fn fast_psf_kept(
    sys: &System,
    field_deg: f64,
    o: &PsfOptions,
    d: &mut Diagnostics,
    force_traced: bool,
    keep: Option<&mut Option<FastState>>,
) -> Result<std::result::Result<Vec<f64>, &'static str>> {
    let beam = Beam::new(sys, field_deg, Aiming::Paraxial)?;
    if beam.object.is_some() {
        return Ok(Err(
            "a finite object: the pupil's flux is not uniform (cos^4 over the pupil), which this path assumes",
        ));
    }
    let chief_launch = beam.launch(0.0, 0.0);
    let Reference {
        chief,
        chief_opl,
        radius,
    } = reference(&beam, &chief_launch)?;
    let n_img = sys.image_index();
    let wl_mm = sys.wavelength_nm * 1e-6;
    let s = samples();
    let t = beam.trace_pupil_soa(&s.px, &s.py);
    if t.status.iter().any(|&c| c != 0) {
        return Ok(Err(
            "a ray of the coarse pupil set did not reach the image (vignetting, TIR or a miss)",
        ));
    }
    let nr = s.px.len();
    let chief_sphere_opl = chief_opl - n_img * radius;
    let v3 = |a: &[f64], k: usize| DVec3::new(a[3 * k], a[3 * k + 1], a[3 * k + 2]);
    let (mut l, mut m, mut w) = (vec![0.0; nr], vec![0.0; nr], vec![0.0; nr]);
    let (mut ex, mut ey) = (0.0f64, 0.0f64);
    for k in 0..nr {
        let (pos, dir) = (v3(&t.position, k), v3(&t.direction, k));
        let Some(tt) = back_to_sphere(pos, dir, chief.p, radius) else {
            return Ok(Err("a ray of the coarse pupil set misses the reference sphere"));
        };
        let opl = t.opl[k] + beam.wavefront_offset(v3(&t.origin, k)) + n_img * tt;
        w[k] = (opl - chief_sphere_opl) / wl_mm;
        // Debye's integral runs over the directions from the sphere point to its centre
        // (not the ray's own direction, which differs by its transverse aberration / R).
        let u = (chief.p - (pos + tt * dir)) / radius;
        l[k] = u.x;
        m[k] = u.y;
        ex = ex.max((pos.x - chief.p.x).abs());
        ey = ey.max((pos.y - chief.p.y).abs());
    }
    // Normalized direction coordinates u = L / rho, v = (M - M_chief) / rho in [-1, 1].
    let mc = chief.d.y;
    let rho = l
        .iter()
        .map(|x| x.abs())
        .chain(m.iter().map(|y| (y - mc).abs()))
        .fold(0.0, f64::max);
    if !(rho > 0.0 && rho.is_finite()) {
        return Ok(Err("degenerate pupil"));
    }
    let u: Vec<f64> = l.iter().map(|x| x / rho).collect();
    let v: Vec<f64> = m.iter().map(|y| (y - mc) / rho).collect();
    // Fits of the lowest degree within tolerance.
    let mut fit = None;
    let mut last_resid = (f64::INFINITY, f64::INFINITY);
    let (pu, pv) = (legendre_table(&u), legendre_table(&v));
    for deg in DEGREES {
        let (te, to) = (terms(deg, 0), terms(deg, 1));
        let (Some((ce, re)), Some((co, ro))) = (lsq(&pu, &pv, &[&w, &s.py], &te), lsq(&pu, &pv, &[&s.px], &to)) else {
            continue;
        };
        last_resid = (re[0], re[1].max(ro[0]));
        if re[0] <= W_TOL_WAVES && re[1] <= P_TOL && ro[0] <= P_TOL {
            fit = Some((deg, te, to, ce, co));
            break;
        }
    }
    // Where no polynomial is within tolerance, each cell gets its own ray (psf/traced.rs).
    if force_traced {
        fit = None;
    }
    let traced = fit.is_none();
    if traced {
        let (dx, dy) = super::traced::extent(&beam, chief.p);
        ex = ex.max(dx);
        ey = ey.max(dy);
    }
    // Affine fits (degree 1) guard against the polynomials' excursions far outside the pupil.
    // (px = pxu u, py = py0 + pyv v by least squares: the degree-1 fits in closed form.)
    let pxu = u.iter().zip(&s.px).map(|(a, b)| a * b).sum::<f64>() / u.iter().map(|a| a * a).sum::<f64>();
    let (nv, sv, svv) = (
        v.len() as f64,
        v.iter().sum::<f64>(),
        v.iter().map(|a| a * a).sum::<f64>(),
    );
    let (sy, svy) = (
        s.py.iter().sum::<f64>(),
        v.iter().zip(&s.py).map(|(a, b)| a * b).sum::<f64>(),
    );
    let det = nv * svv - sv * sv;
    let (py0, pyv) = ((svv * sy - sv * svy) / det, (nv * svy - sv * sy) / det);
    if !(pxu.is_finite() && pxu != 0.0 && py0.is_finite() && pyv.is_finite() && pyv != 0.0) {
        return Ok(Err("degenerate pupil"));
    }

    // Grid: window within half the FFT field, spot within a quarter, pupil_samples across.
    let pix = o.pixel_mm;
    // (Image space is inverted: u < 0 on the traced half px > 0; the fits are odd or even.)
    let (umax, vmin, vmax) = (
        u.iter().map(|x| x.abs()).fold(0.0, f64::max),
        v.iter().cloned().fold(f64::INFINITY, f64::min),
        v.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
    );
    let min_extent = (2.0 * umax).min(vmax - vmin) * rho;
    let want = grid_want(o.pupil_samples, wl_mm, n_img, min_extent, ex.max(ey), o);
    if !(want <= MAX_GRID as f64) {
        return Ok(Err("the FFT grid would exceed 8192"));
    }
    let g = fast_len(want as usize);
    let dl = wl_mm / (n_img * g as f64 * pix);
    let sc = dl / rho; // cell size in u, v
    let half = (g / 2) as f64;
    // Cells: rows b_lo..b_hi, columns t = a - g/2 in 0..=t_hi (x >= 0 half).
    let b_lo = (half + vmin / sc).floor() - 2.0;
    let b_hi = (half + vmax / sc).ceil() + 2.0;
    let t_hi = (umax / sc).ceil() as usize + 2;
    if b_lo < 0.0 || b_hi >= g as f64 || t_hi >= g / 2 {
        return Ok(Err(
            "the pupil does not fit in the direction grid (pixel too coarse for the aperture)",
        ));
    }
    let (b_lo, b_hi) = (b_lo as usize, b_hi as usize);
    let nrow = b_hi - b_lo + 1;
    let h = o.size / 2;
    let ncol = h + 1;

    // Pupil function rows (f32), transformed along x; bins 0..=h kept per row.
    let fft = plan::<f32>(g);
    let scratch_len = fft.get_inplace_scratch_len();
    // A traced pupil's rays go through an unclipped copy of the system, built before the pooled
    // buffers are taken (an engine error here is this path's failure, not the PSF's: the
    // caller falls back).
    let open = if traced {
        match System::new(sys.lens, sys.wavelength_nm) {
            Ok(mut open) => {
                open.clip = false;
                Some(open)
            }
            Err(_) => return Ok(Err("the unclipped system for the traced pupil could not be built")),
        }
    } else {
        None
    };
    let open_beam = match &open {
        Some(open) => match Beam::new(open, field_deg, Aiming::Paraxial) {
            Ok(b) => Some(b),
            Err(_) => return Ok(Err("the unclipped system for the traced pupil could not be built")),
        },
        None => None,
    };
    let mut rows_v = buffer::<f32>(nrow * g);
    let rows = &mut rows_v[..nrow * g];
    let (mut area, mut amp_sum, mut energy) = (0.0f64, 0.0f64, 0.0f64);
    let mut cw_ = CELL_WORK.with(|c| std::mem::take(&mut *c.borrow_mut()));
    let (mut rays_traced, mut newton_iterations) = (nr, 0usize);
    if let Some((deg, te, to, ce, co)) = &fit {
        let (deg, te, to, ce, co) = (*deg, te, to, ce, co);
        let (tw, ty, tx) = (
            Table::new(&ce[0], te, 0, deg),
            Table::new(&ce[1], te, 0, deg),
            Table::new(&co[0], to, 1, deg),
        );
        let nq = deg / 2 + 1;
        cw_.s.clear();
        cw_.s.extend((0..=t_hi).map(|t| (t as f64 * sc) * (t as f64 * sc)));
        // The pupil radius changes by at most about sc |d(px, py)/d(u, v)| per cell (the affine
        // scale, within the map's ~1% distortion), and a cell is partly covered only within
        // 0.71 of that from the edge: delta = one cell's change bounds the rim zone.
        let delta = sc * pxu.abs().max(pyv.abs());
        for (ri, row) in rows.chunks_exact_mut(g).enumerate() {
            let vb = ((b_lo + ri) as f64 - half) * sc;
            let n = row_len((pxu, py0, pyv), sc, vb, t_hi);
            if n == 0 {
                zero_fill(row);
                continue;
            }
            let (a, am, e) = cw_.row(row, [&tw, &tx, &ty], vb, nq, n, sc, delta);
            area += a;
            amp_sum += am;
            energy += e;
        }
    } else if let Some(open_beam) = &open_beam {
        let sphere = super::traced::Sphere {
            chief: chief.p,
            radius,
            n_img,
            chief_sphere_opl,
            wl_mm,
            rho,
            mc,
        };
        match super::traced::fill_rows(open_beam, &sphere, (pxu, py0, pyv), sc, g, b_lo, t_hi, rows) {
            Ok(f) => {
                area = f.area;
                amp_sum = f.amp_sum;
                energy = f.energy;
                rays_traced += f.rays;
                newton_iterations = f.iterations;
                ex = ex.max(f.extent.0);
                ey = ey.max(f.extent.1);
            }
            Err(why) => {
                CELL_WORK.with(|c| *c.borrow_mut() = cw_);
                recycle(rows_v);
                return Ok(Err(why));
            }
        }
    }
    if !((area / PI - 1.0).abs() <= AREA_TOL) {
        CELL_WORK.with(|c| *c.borrow_mut() = cw_);
        recycle(rows_v);
        if traced {
            return Ok(Err("the traced pupil's area differs from the unit circle's"));
        }
        // Fits within tolerance at their rays that stray between them: the same pupil traced
        // cell by cell.
        d.set(
            "pupil_traced_because",
            "the fitted pupil's area differs from the unit circle's",
        );
        return fast_psf_kept(sys, field_deg, o, d, true, keep);
    }
    let mut scratch_v = buffer::<f32>(scratch_len);
    let scratch = &mut scratch_v[..scratch_len];
    fft.process_with_scratch(rows, scratch);
    // Columns m = 0..=h over the rows, transformed along y. Row b goes to bin b - g/2: one
    // run of bins from k0, the rest of each column zero.
    let mut cols_v = buffer::<f32>(ncol * g);
    let cols = &mut cols_v[..ncol * g];
    let k0 = (b_lo + g - g / 2) % g;
    for col in cols.chunks_exact_mut(g) {
        let k1 = k0 + nrow;
        if k1 <= g {
            zero_fill(&mut col[..k0]);
            zero_fill(&mut col[k1..]);
        } else {
            zero_fill(&mut col[k1 - g..k0]);
        }
    }
    // By tiles of TILE rows: each column receives a contiguous run (one cache line).
    const TILE: usize = 8;
    for (t, tile) in rows.chunks(TILE * g).enumerate() {
        let ri0 = t * TILE;
        let nt = tile.len() / g;
        for (mx, col) in cols.chunks_exact_mut(g).enumerate() {
            for i in 0..nt {
                let k = k0 + ri0 + i;
                col[if k >= g { k - g } else { k }] = tile[i * g + mx];
            }
        }
    }
    fft.process_with_scratch(cols, scratch);
    recycle(scratch_v);
    recycle(rows_v);
    // Intensity times pixel area, as a fraction of the entrance-pupil flux:
    // |U|^2 pix^2 = |sum A exp(i phi)|^2 sc^2 / (pi g^2). By tiles of TILE output rows:
    // the columns' runs into a small row-major buffer, then each row with its mirror image
    // (column h + mx and h - mx share the intensity of bin mx).
    let scale = sc * sc / (PI * (g * g) as f64);
    let size = o.size;
    let mut out = take_f64(size * size);
    let tbuf = &mut cw_.tile;
    tbuf.resize(TILE * ncol, 0.0);
    // Row r holds bin r - h: bins g - h..g for rows 0..h, then 0..size - h.
    for (r_lo, r_hi, k_lo) in [(0, h, g - h), (h, size, 0)] {
        for r0 in (r_lo..r_hi).step_by(TILE) {
            let nt = (r_hi - r0).min(TILE);
            let k = k_lo + r0 - r_lo;
            for (mx, col) in cols.chunks_exact(g).enumerate() {
                for (i, zc) in col[k..k + nt].iter().enumerate() {
                    let (re, im) = (zc.re as f64, zc.im as f64);
                    tbuf[i * ncol + mx] = (re * re + im * im) * scale;
                }
            }
            for (i, b) in tbuf.chunks_exact(ncol).enumerate().take(nt) {
                let row = &mut out[(r0 + i) * size..][..size];
                let (left, right) = row.split_at_mut(h);
                right.copy_from_slice(&b[..size - h]);
                for (o, &v) in left.iter_mut().rev().zip(&b[1..=h]) {
                    *o = v;
                }
            }
        }
    }
    CELL_WORK.with(|c| *c.borrow_mut() = cw_);
    let fit_degree = fit.as_ref().map(|f| f.0);
    match (keep, fit) {
        (Some(k), Some((degree, _, _, ce, co))) => {
            let mut ce = ce.into_iter();
            *k = Some(FastState {
                degree,
                w: ce.next().unwrap_or_default(),
                py: ce.next().unwrap_or_default(),
                px: co.into_iter().next().unwrap_or_default(),
                affine: (pxu, py0, pyv),
                g,
                b_lo,
                nrow,
                t_hi,
                sc,
                delta: sc * pxu.abs().max(pyv.abs()),
                scale,
                cols: cols_v,
            });
        }
        (Some(k), None) => {
            *k = None;
            recycle(cols_v);
        }
        _ => recycle(cols_v),
    }
    // Energy in the window.
    let window_energy = super::sum_lanes(&out);

    // Diagnostics and checks, as fft.rs reports them.
    let period = g as f64 * pix;
    let step = ex.max(ey) / period;
    d.set("fft_mode", "direction_grid");
    d.set("chief_x_mm", chief.p.x);
    d.set("chief_y_mm", chief.p.y);
    d.set("transmitted_fraction", 1.0);
    d.set("max_phase_step_waves", step);
    d.set("reference_sphere_radius_mm", radius);
    d.set("rays_traced", rays_traced as f64);
    d.set("rays_missed", 0.0);
    d.set("rays_clipped", 0.0);
    d.set("rays_tir", 0.0);
    d.set("pupil_eval", if traced { "traced" } else { "fit" });
    if traced && !d.values.contains_key("pupil_traced_because") {
        d.set(
            "pupil_traced_because",
            if force_traced {
                "asked for"
            } else {
                "the pupil polynomial fits miss their tolerance"
            },
        );
    }
    if let Some(deg) = fit_degree {
        d.set("pupil_fit_degree", deg as f64);
    } else {
        d.set("pupil_newton_iterations", newton_iterations as f64);
    }
    d.set("pupil_fit_residual_waves", last_resid.0);
    d.set("pupil_fit_residual_coord", last_resid.1);
    d.set("pupil_samples_across", min_extent / dl);
    d.set("pupil_area_error", area / PI - 1.0);
    d.set("distortion_order", 0.0);
    d.set("fft_mirror_symmetry", true);
    if step > 0.5 {
        d.warn(format!(
            "pupil undersampled: the wavefront changes by {step:.2} waves between neighbouring samples (> 0.5); the PSF aliases: increase pupil_samples"
        ));
    }
    report_grid(d, g, (pix, pix), (period, period), (ex, ey), window_energy);
    // The sampled pupil's energy over the whole FFT field (Parseval; the anti-aliased rim
    // sends a little less there than the unit pupil's 1).
    d.set("fft_field_energy", energy / PI);
    d.set("unaberrated_peak", (amp_sum * sc).powi(2) / (PI * (g * g) as f64));
    Ok(Ok(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_cover_is_the_area_inside_the_edge() {
        // Monte Carlo-free check: integrate the indicator on a fine grid.
        for &(d, ang) in &[
            (0.0, 0.3),
            (0.2, 0.0),
            (-0.3, 0.7),
            (0.6, 0.785),
            (-0.65, 1.2),
            (0.1, std::f64::consts::FRAC_PI_2),
        ] {
            let (nx, ny) = (f64::cos(ang), f64::sin(ang));
            let n = 400;
            let mut inside = 0usize;
            for i in 0..n {
                for j in 0..n {
                    let (x, y) = ((i as f64 + 0.5) / n as f64 - 0.5, (j as f64 + 0.5) / n as f64 - 0.5);
                    if nx * x + ny * y <= d {
                        inside += 1;
                    }
                }
            }
            let mc = inside as f64 / (n * n) as f64;
            // The edge r = 1 at signed distance d (cells) along the gradient 0.01 (nx, ny).
            let c = cover_cell(1.0 - 0.01 * d, 0.01 * nx, 0.01 * ny);
            assert!((c - mc).abs() < 4e-3, "d {d} angle {ang}: {c} vs {mc}");
        }
    }

    #[test]
    fn cis_turns_matches_sin_cos() {
        for i in 0..20001 {
            let t = -50.0 + i as f64 * 0.005_000_37;
            let (s, c) = (2.0 * PI * t).sin_cos();
            let (zc, zs) = cis_turns(t);
            assert!(
                (zc - c).abs() < 1e-13 && (zs - s).abs() < 1e-13,
                "t = {t}: {zc} + {zs}i vs {c} + {s}i"
            );
        }
    }

    #[test]
    fn legendre_tables_agree() {
        let (mut p, mut dp) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
        let leg = legendre_monomials();
        for &x in &[-0.9, -0.3, 0.0, 0.45, 1.0] {
            legendre(x, MAX_DEGREE, &mut p, &mut dp);
            for i in 0..=MAX_DEGREE {
                let mono: f64 = (0..=MAX_DEGREE).map(|k| leg[i][k] * x.powi(k as i32)).sum();
                assert!((mono - p[i]).abs() < 1e-12, "P_{i}({x})");
                let h = 1e-6;
                let (mut a, mut b, mut t) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
                legendre(x + h, MAX_DEGREE, &mut a, &mut t);
                legendre(x - h, MAX_DEGREE, &mut b, &mut t);
                assert!(
                    (dp[i] - (a[i] - b[i]) / (2.0 * h)).abs() < 1e-5 * (1.0 + dp[i].abs()),
                    "P'_{i}({x})"
                );
            }
        }
        assert_eq!(fast_len(256), 256);
        assert_eq!(fast_len(180), 192);
        assert_eq!(fast_len(257), 384);
        assert_eq!(fast_len(100), 128);
    }
}
