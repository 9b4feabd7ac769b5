//! The fast FFT's pupil by tracing, for wavefronts no polynomial follows (psf/fast.rs).
//!
//! The fast path needs the pupil function at the cell centres of a grid of image-space
//! direction cosines (u, v). It normally gets W, px and py there from polynomials fitted to
//! about a hundred rays. A strongly aberrated pupil (a wavefront of tens of waves with the
//! structure of a high-order asphere: the 100-300 um spots of fast or far-off designs) is
//! not within 1e-3 waves of any polynomial of degree 12, and the fits give up. Here each
//! cell gets its own ray instead:
//!
//! 1. From the affine map (u, v) -> (px, py) of the coarse rays, Newton's method finds the
//!    entrance-pupil point whose ray reaches the reference sphere at the cell's direction,
//!    with the 2 x 2 Jacobian d(u, v)/d(px, py) by finite differences (three rays per cell
//!    and iteration), all cells of the grid's bounding box at once, through a system whose
//!    clear apertures do not clip (the rim cells lie just outside the pupil).
//! 2. The cell's W is that ray's optical path against the reference sphere (no fit: exact
//!    to the Newton tolerance, NEWTON_TOL in u times dW/du, below 1e-6 waves), its amplitude
//!    sqrt|d(px, py)/d(u, v)|, and its share of the pupil the area fraction of the cell
//!    inside the unit circle (pupil.rs's `cover_cell`, from r = |(px, py)| and its gradient).
//!
//! The rest (mirror symmetry in x, the FFT sized from the spot) is fast.rs's. Cost: about
//! 3 x 5 rays per cell of the bounding box, e.g. 2.4 M rays (0.1 s at 30 M rays/s) for the
//! 565 cells across the pupil of a 1536-point grid, against a minute or more for Huygens
//! over a 246 x 246 window.

use super::pupil::{cover_cell, half_pupil};
use crate::aim::Beam;
use glam::DVec3;
use num_complex::Complex32;

/// Newton stops where the cell's direction is within this of its centre (normalized
/// coordinates u = L / rho, |u| <= 1).
const NEWTON_TOL: f64 = 1e-10;
const NEWTON_MAX_IT: usize = 20;
/// Finite-difference step in entrance-pupil coordinates.
const FD_STEP: f64 = 1e-6;
/// Largest Newton step (pupil radii): keeps the first steps from far-off guesses sane.
const MAX_STEP: f64 = 0.25;
/// Cells traced per engine call (three rays each).
const CHUNK_CELLS: usize = 1 << 16;
/// Cells whose affine guess is beyond this pupil radius are not traced.
const SKIP_RADIUS: f64 = 1.25;
/// Halvings of a step whose rays were lost before the cell is given up.
const MAX_HALVINGS: u8 = 8;
/// From this iteration on, a cell whose point lies beyond SKIP_RADIUS is given up: its
/// direction is outside the pupil's image (unreachable targets oscillate out there).
const GIVE_UP_IT: usize = 3;

/// What the rays of the cells need to know of the reference sphere and the direction grid.
pub(crate) struct Sphere {
    pub chief: DVec3,
    pub radius: f64,
    pub n_img: f64,
    /// Optical path of the chief ray to the sphere (the W = 0 reference).
    pub chief_sphere_opl: f64,
    pub wl_mm: f64,
    /// Direction-cosine scale (u = L / rho, v = (M - mc) / rho).
    pub rho: f64,
    pub mc: f64,
}

/// The filled rows' sums (as fast.rs's rows report them) and what the rays saw.
pub(crate) struct Filled {
    /// Pupil area (entrance-pupil units) and energy of the sampled field, amplitude sum.
    pub area: f64,
    pub energy: f64,
    pub amp_sum: f64,
    pub rays: usize,
    /// Largest |x|, |y| of the cells' image points from the chief ray's (mm).
    pub extent: (f64, f64),
    /// Newton iterations of the slowest cell.
    pub iterations: usize,
}

struct Rays {
    u: Vec<f64>,
    v: Vec<f64>,
    w: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    ok: Vec<bool>,
}

/// Traces pupil points: normalized direction (u, v) at the reference sphere, W (waves) and
/// the image point's offset from the chief ray's.
fn trace(beam: &Beam, s: &Sphere, px: &[f64], py: &[f64]) -> Rays {
    let t = beam.trace_pupil_soa(px, py);
    let n = px.len();
    let mut r = Rays {
        u: vec![0.0; n],
        v: vec![0.0; n],
        w: vec![0.0; n],
        x: vec![0.0; n],
        y: vec![0.0; n],
        ok: vec![false; n],
    };
    let v3 = |a: &[f64], k: usize| DVec3::new(a[3 * k], a[3 * k + 1], a[3 * k + 2]);
    for k in 0..n {
        if t.status[k] != 0 {
            continue;
        }
        let (pos, dir) = (v3(&t.position, k), v3(&t.direction, k));
        let Some(tt) = super::pupil::back_to_sphere(pos, dir, s.chief, s.radius) else {
            continue;
        };
        let opl = t.opl[k] + beam.wavefront_offset(v3(&t.origin, k)) + s.n_img * tt;
        // Debye's integral runs over the directions from the sphere point to its centre.
        let d = (s.chief - (pos + tt * dir)) / s.radius;
        r.u[k] = d.x / s.rho;
        r.v[k] = (d.y - s.mc) / s.rho;
        r.w[k] = (opl - s.chief_sphere_opl) / s.wl_mm;
        r.x[k] = pos.x - s.chief.x;
        r.y[k] = pos.y - s.chief.y;
        r.ok[k] = r.u[k].is_finite() && r.v[k].is_finite() && r.w[k].is_finite();
    }
    r
}

/// Fills `rows` (nrow rows of `g` cells: row ri at v = (b_lo + ri - g/2) sc, cells t = 0..=t_hi
/// at u = t sc and their mirror images g - t) with the traced pupil field. `affine`: the
/// coarse rays' px = pxu u, py = py0 + pyv v. Err: a cell inside the pupil failed.
#[allow(clippy::too_many_arguments)]
pub(crate) fn fill_rows(
    open: &Beam,
    s: &Sphere,
    affine: (f64, f64, f64),
    sc: f64,
    g: usize,
    b_lo: usize,
    t_hi: usize,
    rows: &mut [Complex32],
) -> Result<Filled, &'static str> {
    let nrow = rows.len() / g;
    let ncell = t_hi + 1;
    let n = nrow * ncell;
    let half = (g / 2) as f64;
    let (pxu, py0, pyv) = affine;
    // The map's orientation at the pupil's centre (the affine map's): Newton stays on the
    // branch of the map that holds the pupil.
    let sign = (pxu * pyv).signum();
    let target = |k: usize| -> (f64, f64) { ((k % ncell) as f64 * sc, ((b_lo + k / ncell) as f64 - half) * sc) };
    let (mut px, mut py) = (vec![0.0; n], vec![0.0; n]);
    for k in 0..n {
        let (u, v) = target(k);
        px[k] = pxu * u;
        py[k] = py0 + pyv * v;
    }
    // The last point of each cell whose rays traced, and the step halvings since.
    let (mut last_ok, mut halvings): (Vec<Option<(f64, f64)>>, Vec<u8>) = (vec![None; n], vec![0; n]);
    // Per cell, once converged: W, d(px, py)/d(u, v) (row-major).
    let mut w = vec![0.0; n];
    let mut jinv = vec![[0.0f64; 4]; n];
    // 0 pending, 1 converged, 2 given up.
    let mut state = vec![0u8; n];
    // Cells whose affine guess lies far outside the pupil are dark: not traced (a pupil whose
    // map departs from affine by more shows in the area check).
    let mut pending: Vec<usize> = (0..n).filter(|&k| px[k].hypot(py[k]) <= SKIP_RADIUS).collect();
    let (mut rays, mut iterations) = (0usize, 0usize);
    let mut extent = (0.0f64, 0.0f64);
    let mut image = vec![(0.0f64, 0.0f64); n];
    let (mut xs, mut ys) = (Vec::with_capacity(3 * CHUNK_CELLS), Vec::with_capacity(3 * CHUNK_CELLS));
    for it in 0..NEWTON_MAX_IT {
        if pending.is_empty() {
            break;
        }
        iterations = it + 1;
        let mut still = Vec::with_capacity(pending.len());
        // By chunks of cells: the traced arrays stay small whatever the grid.
        for chunk in pending.chunks(CHUNK_CELLS) {
            xs.clear();
            ys.clear();
            for &k in chunk {
                xs.extend([px[k], px[k] + FD_STEP, px[k]]);
                ys.extend([py[k], py[k], py[k] + FD_STEP]);
            }
            let r = trace(open, s, &xs, &ys);
            rays += xs.len();
            for (i, &k) in chunk.iter().enumerate() {
                let (a, b, c) = (3 * i, 3 * i + 1, 3 * i + 2);
                let j = [
                    (r.u[b] - r.u[a]) / FD_STEP,
                    (r.u[c] - r.u[a]) / FD_STEP,
                    (r.v[b] - r.v[a]) / FD_STEP,
                    (r.v[c] - r.v[a]) / FD_STEP,
                ];
                let det = j[0] * j[3] - j[1] * j[2];
                if !(r.ok[a] && r.ok[b] && r.ok[c] && det * sign > 1e-12 && det.is_finite()) {
                    // Rays lost here (beyond the lens's reach, a miss or TIR), or past a fold of
                    // the map (the Jacobian's sign turned): back half way towards the last point
                    // on this side, a few times, then give the cell up.
                    match last_ok[k] {
                        Some((x0, y0)) if halvings[k] < MAX_HALVINGS => {
                            halvings[k] += 1;
                            px[k] = 0.5 * (x0 + px[k]);
                            py[k] = 0.5 * (y0 + py[k]);
                            still.push(k);
                        }
                        _ => state[k] = 2,
                    }
                    continue;
                }
                last_ok[k] = Some((px[k], py[k]));
                let inv = [j[3] / det, -j[1] / det, -j[2] / det, j[0] / det];
                let (ut, vt) = target(k);
                let (eu, ev) = (ut - r.u[a], vt - r.v[a]);
                if eu.abs().max(ev.abs()) <= NEWTON_TOL {
                    state[k] = 1;
                    w[k] = r.w[a];
                    jinv[k] = inv;
                    image[k] = (r.x[a], r.y[a]);
                    continue;
                }
                let (mut dx, mut dy) = (inv[0] * eu + inv[1] * ev, inv[2] * eu + inv[3] * ev);
                let len = dx.hypot(dy);
                if len > MAX_STEP {
                    dx *= MAX_STEP / len;
                    dy *= MAX_STEP / len;
                }
                px[k] += dx;
                py[k] += dy;
                if it >= GIVE_UP_IT && px[k].hypot(py[k]) > SKIP_RADIUS {
                    state[k] = 2;
                    continue;
                }
                still.push(k);
            }
        }
        pending = still;
    }
    for &k in &pending {
        state[k] = 2;
    }
    // A cell given up is one whose direction no ray of the open system reaches on the branch
    // of the map that holds the pupil: beyond a fold of the map or the lens's reach. Where the
    // fold lies outside the pupil, such cells are outside it too. Where it lies inside, the
    // cells beyond it are missing from the pupil, and the area check (fast.rs) sees them.
    let (mut area, mut energy, mut amp_sum) = (0.0, 0.0, 0.0);
    for (ri, row) in rows.chunks_exact_mut(g).enumerate() {
        super::fft::zero_fill(row);
        for t in 0..ncell {
            let k = ri * ncell + t;
            if state[k] != 1 {
                continue;
            }
            let m = &jinv[k];
            let jac = (m[0] * m[3] - m[1] * m[2]).abs();
            let r = px[k].hypot(py[k]);
            let ir = sc / r.max(1e-300);
            // gradient of r in cells: d r / d(u, v) = (px d px + py d py) / r
            let cov = cover_cell(
                r,
                (px[k] * m[0] + py[k] * m[2]) * ir,
                (px[k] * m[1] + py[k] * m[3]) * ir,
            );
            if cov <= 0.0 {
                continue;
            }
            let amp = jac.sqrt() * cov;
            extent = (extent.0.max(image[k].0.abs()), extent.1.max(image[k].1.abs()));
            let mult = if t == 0 { 1.0 } else { 2.0 };
            area += mult * jac * cov;
            energy += mult * jac * cov * cov;
            amp_sum += mult * amp;
            let ph = 2.0 * std::f64::consts::PI * w[k].rem_euclid(1.0);
            let z = Complex32::new((amp * ph.cos()) as f32, (amp * ph.sin()) as f32);
            row[t] = z;
            if t > 0 {
                row[g - t] = z;
            }
        }
    }
    Ok(Filled {
        area: area * sc * sc,
        energy: energy * sc * sc,
        amp_sum,
        rays,
        extent,
        iterations,
    })
}

/// Rays across the pupil diameter of the set that sizes the grid for a traced pupil.
const EXTENT_SAMPLES: usize = 48;

/// The spot's extent about the chief ray (largest |x|, |y|, mm) from a denser set of rays than
/// fast.rs's coarse one (EXTENT_SAMPLES across the pupil, and as many on its rim): the coarse
/// set under-reports the spot of a pupil that no polynomial follows, and the grid is sized
/// from it.
pub(crate) fn extent(beam: &Beam, chief: DVec3) -> (f64, f64) {
    let (px, py) = half_pupil(EXTENT_SAMPLES, EXTENT_SAMPLES + 1, 0.999);
    let t = beam.trace_pupil_soa(&px, &py);
    let (mut ex, mut ey) = (0.0f64, 0.0f64);
    for k in 0..px.len() {
        if t.status[k] == 0 {
            ex = ex.max((t.position[3 * k] - chief.x).abs());
            ey = ey.max((t.position[3 * k + 1] - chief.y).abs());
        }
    }
    (ex, ey)
}

#[cfg(test)]
mod tests {
    use crate::psf::fast::fast_psf_pupil;
    use crate::psf::{Diagnostics, Method, PsfOptions};
    use crate::trace::System;
    use crate::Lens;

    /// A biconvex singlet at f/6 (f ~ 49 mm) a little behind its paraxial focus: a PSF of
    /// some tens of um with spherical aberration and coma, whose pupil the fits follow.
    fn singlet() -> Lens {
        let js = serde_json::json!({
            "aperture": {"type": "epd", "value": 8.0}, "wavelengths_nm": [550.0],
            "surfaces": [
                {"radius": 50.0, "thickness": 5.0, "material": {"n": 1.5168}, "stop": true},
                {"radius": -50.0, "thickness": 47.0, "material": "air"}
            ]
        });
        Lens::from_json(&js.to_string()).unwrap()
    }

    fn rel_l1(a: &[f64], b: &[f64]) -> f64 {
        let (sa, sb): (f64, f64) = (a.iter().sum(), b.iter().sum());
        a.iter().zip(b).map(|(x, y)| (x / sa - y / sb).abs()).sum()
    }

    /// Where the polynomial fits hold, the traced pupil (one ray per direction cell, no fit)
    /// gives the same PSF: two ways to the same pupil function, within 0.3 % relative L1.
    #[test]
    fn traced_pupil_matches_the_fitted_one_where_both_apply() {
        let lens = singlet();
        let o = PsfOptions {
            method: Method::Fft,
            fast: true,
            size: 96,
            pixel_mm: 1e-3,
            pupil_samples: 64,
            ..Default::default()
        };
        for field in [0.0, 3.0, 6.0] {
            let sys = System::new(&lens, 550.0).unwrap();
            let (mut d_fit, mut d_tr) = (Diagnostics::default(), Diagnostics::default());
            let fit = fast_psf_pupil(&sys, field, &o, &mut d_fit, false).unwrap().unwrap();
            let tr = fast_psf_pupil(&sys, field, &o, &mut d_tr, true).unwrap().unwrap();
            assert_eq!(d_fit.values["pupil_eval"], "fit");
            assert_eq!(d_tr.values["pupil_eval"], "traced");
            let e = rel_l1(&fit, &tr);
            let (sf, st): (f64, f64) = (fit.iter().sum(), tr.iter().sum());
            println!("{field} deg: rel L1 {e:.2e}, energy {sf:.6} / {st:.6}");
            assert!(e <= 3e-3, "{field} deg: traced vs fitted pupil rel L1 {e:.4}");
            assert!((sf - st).abs() <= 1e-3 * sf, "{field} deg: window energy {sf} vs {st}");
            assert!(tr.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
    }
}
