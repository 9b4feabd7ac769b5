//! Sampling the pupil for one field and wavelength: a square grid of rays over the unit
//! pupil (cell centres inside the unit circle), traced to the image plane, with each ray's
//! optical path difference against the reference sphere centred on the chief-ray image
//! point (radius: chief-ray distance to the paraxial exit pupil), its image-space direction
//! cosines, its flux, and the local Jacobian d(L, M)/d(grid index).

use super::Diagnostics;
use crate::aim::{Aiming, Beam, Launch};
use crate::error::{EngineError, Result};
use crate::trace::{End, RayState, Status, System};
use glam::DVec3;
use std::cell::RefCell;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

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
    fn empty() -> Pupil {
        Pupil {
            n: 0,
            wavelength_mm: 0.0,
            n_image: 1.0,
            inside: vec![],
            valid: vec![],
            opd_waves: vec![],
            flux: vec![],
            l: vec![],
            m: vec![],
            jacobian: vec![],
            sphere: vec![],
            image: vec![],
            chief: DVec3::ZERO,
            chief_dir: DVec3::ZERO,
            radius: 0.0,
            launched_flux_mm2: 0.0,
            status_counts: [0; 5],
        }
    }

    #[inline]
    pub fn coord(&self, i: usize) -> f64 {
        -1.0 + (2.0 * i as f64 + 1.0) / self.n as f64
    }

    pub fn transmitted_fraction(&self) -> f64 {
        self.flux
            .iter()
            .zip(&self.valid)
            .filter(|(_, v)| **v)
            .map(|(f, _)| f)
            .sum()
    }

    pub fn n_valid(&self) -> usize {
        self.valid.iter().filter(|v| **v).count()
    }

    /// Samples across the transmitted pupil where it is narrowest: the most valid samples
    /// in any grid column (its extent along y) or in any grid row (along x), whichever is
    /// fewer. A full pupil has `n`; a sliver at the vignetting cliff a few.
    pub fn samples_across(&self) -> usize {
        let n = self.n;
        let mut cols = vec![0usize; n];
        let mut widest_row = 0;
        for row in self.valid.chunks_exact(n) {
            let mut c = 0;
            for (k, &v) in cols.iter_mut().zip(row) {
                *k += v as usize;
                c += v as usize;
            }
            widest_row = widest_row.max(c);
        }
        widest_row.min(cols.into_iter().max().unwrap_or(0))
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

/// Fewest samples across the transmitted pupil that resolve its shape (see
/// `check_samples_across`).
pub const MIN_SAMPLES_ACROSS: usize = 8;

/// Records the samples across the transmitted pupil (`pupil_samples_across`) and warns
/// where they are fewer than `MIN_SAMPLES_ACROSS`: at the vignetting cliff the beam is cut
/// down to a sliver a few samples wide, whose edges (and so the PSF's extent across it, and
/// the transmitted fraction) are quantized to the grid, and the PSF's error grows about as
/// 1 / w: ~16% relative L1 for the FFT PSF of a band 3 samples across against 512 samples,
/// ~3% at 16 across (tests/failure_modes.rs). Cheap: one pass over the validity mask.
pub fn check_samples_across(p: &Pupil, d: &mut Diagnostics) {
    let w = p.samples_across();
    d.set("pupil_samples_across", w as f64);
    if w < MIN_SAMPLES_ACROSS {
        let need = (p.n * MIN_SAMPLES_ACROSS).div_ceil(w.max(1));
        d.warn(format!(
            "pupil sliver: the transmitted pupil is only {w} samples across ({:.1}% of the launched flux arrives; a field at the vignetting cliff?): its edges, the PSF and the transmitted fraction are quantized to the pupil grid: increase pupil_samples to at least {need}",
            100.0 * p.transmitted_fraction()
        ));
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
                let pivot = a[col];
                for (x, p) in a[r].iter_mut().zip(pivot) {
                    *x -= f * p;
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
    let Reference {
        chief,
        chief_opl,
        radius,
    } = reference(&beam, &chief_launch)?;
    let n_img = sys.image_index();
    let grid = grid(n);
    let nn = n * n;
    let mut p = SPARE.with(|s| s.borrow_mut().take()).unwrap_or_else(Pupil::empty);
    p.n = n;
    p.wavelength_mm = sys.wavelength_nm * 1e-6;
    p.n_image = n_img;
    reset(&mut p.inside, nn, false);
    reset(&mut p.valid, nn, false);
    reset(&mut p.opd_waves, nn, 0.0);
    reset(&mut p.flux, nn, 0.0);
    reset(&mut p.l, nn, 0.0);
    reset(&mut p.m, nn, 0.0);
    reset(&mut p.jacobian, nn, 0.0);
    reset(&mut p.sphere, nn, DVec3::ZERO);
    reset(&mut p.image, nn, DVec3::ZERO);
    p.chief = chief.p;
    p.chief_dir = chief.d;
    p.radius = radius;
    p.launched_flux_mm2 = 0.0;
    p.status_counts = [0; 5];
    // The chief ray crosses the sphere a distance R before its image point.
    let ctx = RayCtx {
        chief: chief.p,
        radius,
        n_img,
        chief_sphere_opl: chief_opl - n_img * radius,
        cell: (2.0 / n as f64).powi(2),
        beam: &beam,
    };
    let mut total = 0.0;
    match aiming {
        // Paraxial launches all carry the same area: trace straight into flat arrays.
        Aiming::Paraxial => {
            let t = beam.trace_pupil_soa(&grid.px, &grid.py);
            let v3 = |a: &[f64], k: usize| DVec3::new(a[3 * k], a[3 * k + 1], a[3 * k + 2]);
            for (k, &j) in grid.idx.iter().enumerate() {
                let o = v3(&t.origin, k);
                total += take_ray(
                    &mut p,
                    &ctx,
                    j,
                    o,
                    beam.paraxial_flux_weight(o),
                    Status::from_code(t.status[k]),
                    v3(&t.position, k),
                    v3(&t.direction, k),
                    t.opl[k],
                );
            }
        }
        Aiming::Real => {
            let (launches, rays) = beam.trace_pupil(&grid.px, &grid.py);
            for ((&j, l), r) in grid.idx.iter().zip(&launches).zip(&rays) {
                total += take_ray(
                    &mut p,
                    &ctx,
                    j,
                    l.origin,
                    beam.flux_weight(l),
                    r.status,
                    r.p,
                    r.d,
                    r.opl,
                );
            }
        }
    }
    p.launched_flux_mm2 = total;
    if total > 0.0 {
        p.flux.iter_mut().for_each(|f| *f /= total);
    }
    if p.n_valid() == 0 {
        let counts = p.status_counts;
        recycle(p);
        return Err(EngineError::Psf(format!(
            "no ray of the {}-sample pupil reaches the image at {field_deg} deg, {:.1} nm (status counts ok/missed/clipped/TIR/invalid = {:?})",
            grid.idx.len(),
            sys.wavelength_nm,
            counts
        )));
    }
    jacobians(&mut p);
    Ok(p)
}

/// Largest reference-sphere radius (mm) whose OPD keeps ~1e-9 mm of precision in f64.
pub const MAX_REFERENCE_RADIUS_MM: f64 = 1e7;

/// The chief ray of a beam and the reference sphere: centred on the chief ray's image
/// point, through its crossing of the paraxial exit-pupil plane.
pub(crate) struct Reference {
    pub chief: RayState,
    /// Optical path of the chief ray from the incident plane wavefront to the image.
    pub chief_opl: f64,
    pub radius: f64,
}

pub(crate) fn reference(beam: &Beam, chief_launch: &Launch) -> Result<Reference> {
    let sys = beam.sys;
    let chief = sys.trace(chief_launch.origin, chief_launch.dir, End::Image);
    if !chief.ok() {
        return Err(EngineError::Trace(format!(
            "chief ray at {} deg, {:.1} nm: {:?} at surface {}",
            beam.field_deg,
            sys.wavelength_nm,
            chief.status,
            chief.surface + 1
        )));
    }
    let chief_opl = chief.opl + beam.wavefront_offset(chief_launch.origin);
    let z_xp = sys.lens.image_z + beam.par.exit_pupil_z;
    let radius = if beam.par.exit_pupil_z.is_finite() {
        let t = (z_xp - chief.p.z) / chief.d.z;
        (t * chief.d).length()
    } else {
        f64::INFINITY
    };
    // Beyond MAX_REFERENCE_RADIUS_MM the sphere's sag across the beam is lost in the rounding
    // of R^2 in `back_to_sphere` (an image-space telecentric lens whose exit pupil the
    // paraxial trace puts at ~1e12 mm): refused as at infinity.
    if !(radius.is_finite() && radius > 0.0 && radius < MAX_REFERENCE_RADIUS_MM) {
        return Err(EngineError::Psf(format!("exit pupil at infinity (image-space telecentric; reference sphere radius {radius:.3e} mm): reference sphere undefined")));
    }
    Ok(Reference {
        chief,
        chief_opl,
        radius,
    })
}

/// Signed distance t (< 0) back along a ray from its image-plane point `pos` (unit
/// direction `dir`) to the reference sphere of `radius` about `chief`; None if it misses.
#[inline(always)]
pub(crate) fn back_to_sphere(pos: DVec3, dir: DVec3, chief: DVec3, radius: f64) -> Option<f64> {
    let v = pos - chief;
    let vd = v.dot(dir);
    let disc = vd * vd - v.length_squared() + radius * radius;
    if disc < 0.0 {
        return None;
    }
    Some(-vd - disc.sqrt())
}

struct RayCtx<'b, 's, 'l> {
    chief: DVec3,
    radius: f64,
    n_img: f64,
    chief_sphere_opl: f64,
    cell: f64,
    beam: &'b Beam<'s, 'l>,
}

/// Records one traced ray of grid cell j (launched at `origin` with flux weight `weight`)
/// in the pupil; returns its flux.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn take_ray(
    p: &mut Pupil,
    c: &RayCtx,
    j: usize,
    origin: DVec3,
    weight: f64,
    status: Status,
    pos: DVec3,
    dir: DVec3,
    opl: f64,
) -> f64 {
    p.inside[j] = true;
    let f = weight * c.cell;
    p.flux[j] = f;
    p.status_counts[status as usize] += 1;
    if status != Status::Ok {
        return f;
    }
    let Some(t) = back_to_sphere(pos, dir, c.chief, c.radius) else {
        p.status_counts[Status::Ok as usize] -= 1;
        p.status_counts[Status::Missed as usize] += 1;
        return f;
    };
    let opl = opl + c.beam.wavefront_offset(origin) + c.n_img * t;
    p.valid[j] = true;
    let s = pos + t * dir;
    p.sphere[j] = s;
    p.image[j] = pos;
    // Debye's integral runs over the directions from the sphere point to its centre (not
    // the ray's own direction, which differs by the transverse ray aberration / R).
    let u = (c.chief - s) / c.radius;
    p.l[j] = u.x;
    p.m[j] = u.y;
    p.opd_waves[j] = (opl - c.chief_sphere_opl) / p.wavelength_mm;
    f
}

/// The grid's cell centres inside the unit circle: x, y and cell index (row = y).
struct Grid {
    n: usize,
    px: Vec<f64>,
    py: Vec<f64>,
    idx: Vec<usize>,
}

thread_local! {
    /// The last grid built on this thread, and a pupil whose buffers can be reused.
    static GRID: RefCell<Option<Arc<Grid>>> = const { RefCell::new(None) };
    static SPARE: RefCell<Option<Pupil>> = const { RefCell::new(None) };
}

fn grid(n: usize) -> Arc<Grid> {
    GRID.with(|c| {
        let mut c = c.borrow_mut();
        if let Some(g) = c.as_ref().filter(|g| g.n == n) {
            return g.clone();
        }
        let coord = |i: usize| -1.0 + (2.0 * i as f64 + 1.0) / n as f64;
        let mut g = Grid {
            n,
            px: vec![],
            py: vec![],
            idx: vec![],
        };
        for b in 0..n {
            for a in 0..n {
                let (x, y) = (coord(a), coord(b));
                if x * x + y * y <= 1.0 {
                    g.px.push(x);
                    g.py.push(y);
                    g.idx.push(b * n + a);
                }
            }
        }
        let g = Arc::new(g);
        *c = Some(g.clone());
        g
    })
}

fn reset<T: Clone>(v: &mut Vec<T>, n: usize, x: T) {
    v.clear();
    v.resize(n, x);
}

/// Hands a pupil that is no longer needed back, so that the next `sample_pupil` on this
/// thread reuses its buffers instead of allocating (and page-faulting) fresh ones.
pub fn recycle(p: Pupil) {
    SPARE.with(|s| *s.borrow_mut() = Some(p));
}

/// d(L, M)/d(a, b) by central differences where both neighbours are valid, one-sided
/// otherwise, and the grid-average slope for isolated samples.
fn jacobians(p: &mut Pupil) {
    let n = p.n;
    let Pupil {
        valid,
        l,
        m,
        jacobian: jac,
        ..
    } = p;
    // Difference over the valid neighbours lo = j - step and/or hi = j + step (one at least).
    #[inline(always)]
    fn diff(v: &[f64], j: usize, step: usize, lo: bool, hi: bool) -> f64 {
        if lo && hi {
            0.5 * (v[j + step] - v[j - step])
        } else if hi {
            v[j + step] - v[j]
        } else {
            v[j] - v[j - step]
        }
    }
    let (mut sum, mut cnt) = (0.0, 0usize);
    for b in 0..n {
        for a in 0..n {
            let j = b * n + a;
            if !valid[j] {
                jac[j] = 0.0;
                continue;
            }
            let (lo_a, hi_a) = (a > 0 && valid[j - 1], a + 1 < n && valid[j + 1]);
            let (lo_b, hi_b) = (b > 0 && valid[j - n], b + 1 < n && valid[j + n]);
            if (lo_a || hi_a) && (lo_b || hi_b) {
                let (la, ma) = (diff(l, j, 1, lo_a, hi_a), diff(m, j, 1, lo_a, hi_a));
                let (lb, mb) = (diff(l, j, n, lo_b, hi_b), diff(m, j, n, lo_b, hi_b));
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
        if valid[j] && *v < 0.0 {
            *v = mean;
        }
    }
}

// The fast FFT's half pupil (fast.rs, and traced.rs for the cells no polynomial follows).

/// Entrance-pupil points of the half pupil px >= 0 (a field along y images it mirror
/// symmetric): the cell centres of an nt x nt grid over [-1, 1]^2 inside the unit circle, then
/// `n_rim` points on the half circle of radius `r_rim` from py = -r_rim to py = r_rim.
pub(crate) fn half_pupil(nt: usize, n_rim: usize, r_rim: f64) -> (Vec<f64>, Vec<f64>) {
    let coord = |i: usize| -1.0 + (2.0 * i as f64 + 1.0) / nt as f64;
    let (mut px, mut py) = (vec![], vec![]);
    for b in 0..nt {
        for a in nt / 2..nt {
            let (x, y) = (coord(a), coord(b));
            if x * x + y * y <= 1.0 {
                px.push(x);
                py.push(y);
            }
        }
    }
    for k in 0..n_rim {
        let phi = -FRAC_PI_2 + PI * k as f64 / (n_rim - 1) as f64;
        let x = if k == 0 || k == n_rim - 1 { 0.0 } else { phi.cos() };
        px.push(r_rim * x);
        py.push(r_rim * phi.sin());
    }
    (px, py)
}

/// Area fraction of the unit cell inside the pupil edge, branch free: d = signed distance
/// (cells) from the cell centre to the edge (> 0 inside), (gx, gy) the gradient of r in
/// cells (n = g / |g|), r the pupil radius at the centre.
#[inline(always)]
pub(crate) fn cover_cell(r: f64, gx: f64, gy: f64) -> f64 {
    let gn = (gx * gx + gy * gy).sqrt();
    let d = (1.0 - r) / gn;
    let (ax, ay) = (gx.abs() / gn, gy.abs() / gn);
    let (a, b) = (ax.max(ay), ax.min(ay));
    let (lo, hi) = (0.5 * (a - b), 0.5 * (a + b));
    let dd = d.max(-hi).min(hi);
    let q1 = (dd + hi) * (dd + hi) / (2.0 * a * b);
    let q2 = 0.5 + dd / a;
    let q3 = 1.0 - (hi - dd) * (hi - dd) / (2.0 * a * b);
    let c = if dd < -lo {
        q1
    } else if dd <= lo {
        q2
    } else {
        q3
    };
    // Deep inside (also where the gradient vanishes, at the pupil centre): fully covered.
    if r < 0.5 || d >= hi {
        1.0
    } else if d <= -hi {
        0.0
    } else {
        c
    }
}
