//! Geometric PSF: the spot diagram of a pupil grid, made noise-free by interpolation.
//!
//! Each traced ray stands for its pupil cell (a square of side 2 / N). Binning one point per
//! cell puts shot noise into the PSF (a spot of P pixels from R rays: ~sqrt(P / R) relative
//! L1), which made the plain spot diagram useless for spots much larger than a pixel. Here
//! each cell is split into M x M sub-cells (M sized per cell so that neighbouring sub-points
//! land at most `SUB_SPACING_PX` output pixels apart, at most `MAX_SUB`), each sub-point's
//! image position is interpolated from the traced rays around it (bilinear over the four
//! rays of the sub-point's quadrant of the cell; over three where the diagonal ray is lost;
//! the cell's own ray and its image-position gradient where a side neighbour is lost: the
//! pupil's rim and vignetted rays), and the cell's flux is shared among its sub-points and
//! splatted bilinearly onto the output pixels. The map is then followed at N M samples across
//! the pupil for the cost of N^2 traced rays; cells whose image lies wholly outside the
//! window are skipped, so a spot far larger than the window costs no more than one that
//! fits. The pupil's rim stays the grid's staircase (cells whose centre lies inside the unit
//! circle), an error of order 1 / N of the flux that auto's model carries.

use super::pupil::Pupil;
use super::{Diagnostics, PsfOptions};

/// Largest distance between neighbouring sub-points on the image (output pixels).
pub const SUB_SPACING_PX: f64 = 0.25;
/// Most sub-points per cell side.
pub const MAX_SUB: usize = 64;

/// Image position of a sub-point at (u, v) in a cell's quadrant: P = A + |u| E1 + |v| E2 +
/// |u||v| E12 (pixels).
#[derive(Clone, Copy, Default)]
struct Quad {
    a: [f64; 2],
    e1: [f64; 2],
    e2: [f64; 2],
    e12: [f64; 2],
}

/// Adds `w` at (x, y) (pixel units, pixel c centred at c) to the four nearest pixels.
#[inline(always)]
fn splat(out: &mut [f64], s: usize, x: f64, y: f64, w: f64) {
    let fs = s as f64;
    if !(x > -1.0 && x < fs && y > -1.0 && y < fs) {
        return;
    }
    let (cx, cy) = (x.floor(), y.floor());
    let (fx, fy) = (x - cx, y - cy);
    let (c, r) = (cx as isize, cy as isize);
    let si = s as isize;
    let mut add = |r: isize, c: isize, v: f64| {
        if r >= 0 && c >= 0 && r < si && c < si {
            out[r as usize * s + c as usize] += v;
        }
    };
    add(r, c, w * (1.0 - fx) * (1.0 - fy));
    add(r, c + 1, w * fx * (1.0 - fy));
    add(r + 1, c, w * (1.0 - fx) * fy);
    add(r + 1, c + 1, w * fx * fy);
}

/// The interpolated spot of `p` on the output grid (fraction of the launched flux per pixel);
/// returns the PSF, the most sub-points per cell side used and the flux share of cells
/// whose sub-points were capped at `MAX_SUB` (coarser than `SUB_SPACING_PX`).
fn smooth_spot(p: &Pupil, o: &PsfOptions) -> (Vec<f64>, usize, f64) {
    let s = o.size;
    let n = p.n;
    let h = (s / 2) as f64;
    let mut out = vec![0.0; s * s];
    let pos: Vec<[f64; 2]> = p
        .image
        .iter()
        .map(|q| [(q.x - p.chief.x) / o.pixel_mm + h, (q.y - p.chief.y) / o.pixel_mm + h])
        .collect();
    let ok = |a: isize, b: isize| {
        a >= 0 && b >= 0 && (a as usize) < n && (b as usize) < n && p.valid[b as usize * n + a as usize]
    };
    let at = |a: isize, b: isize| pos[b as usize * n + a as usize];
    let sub = |x: [f64; 2], y: [f64; 2]| [x[0] - y[0], x[1] - y[1]];
    let norm = |x: [f64; 2]| x[0].hypot(x[1]);
    let (mut most, mut capped) = (1usize, 0.0f64);
    let fs = s as f64;
    for b in 0..n as isize {
        for a in 0..n as isize {
            if !ok(a, b) {
                continue;
            }
            let j = b as usize * n + a as usize;
            let pj = pos[j];
            // Image-position gradient per grid step: central, one-sided or none.
            let grad = |da: isize, db: isize| -> [f64; 2] {
                match (ok(a - da, b - db), ok(a + da, b + db)) {
                    (true, true) => {
                        let d = sub(at(a + da, b + db), at(a - da, b - db));
                        [0.5 * d[0], 0.5 * d[1]]
                    }
                    (false, true) => sub(at(a + da, b + db), pj),
                    (true, false) => sub(pj, at(a - da, b - db)),
                    (false, false) => [0.0, 0.0],
                }
            };
            let (ga, gb) = (grad(1, 0), grad(0, 1));
            // Span of the cell on the image: its gradients and its eight neighbours' offsets.
            let mut span = norm(ga).max(norm(gb));
            let mut reach = [0.5 * (ga[0].abs() + gb[0].abs()), 0.5 * (ga[1].abs() + gb[1].abs())];
            for db in -1..=1isize {
                for da in -1..=1isize {
                    if (da, db) != (0, 0) && ok(a + da, b + db) {
                        let d = sub(at(a + da, b + db), pj);
                        if da == 0 || db == 0 {
                            span = span.max(norm(d));
                        }
                        reach[0] = reach[0].max(0.5 * d[0].abs());
                        reach[1] = reach[1].max(0.5 * d[1].abs());
                    }
                }
            }
            // Wholly outside the window (with the splat's one pixel): nothing to add.
            if pj[0] + reach[0] <= -1.0 || pj[0] - reach[0] >= fs || pj[1] + reach[1] <= -1.0 || pj[1] - reach[1] >= fs
            {
                continue;
            }
            let want = (span / SUB_SPACING_PX).ceil().max(1.0);
            let m = if want > MAX_SUB as f64 {
                capped += p.flux[j];
                MAX_SUB
            } else {
                want as usize
            };
            most = most.max(m);
            // The four quadrants (su, sv) of the cell.
            let mut quads = [Quad::default(); 4];
            for (q, quad) in quads.iter_mut().enumerate() {
                let (su, sv) = (if q & 1 == 1 { 1 } else { -1 }, if q & 2 == 2 { 1 } else { -1 });
                let (ea, eb, dg) = (ok(a + su, b), ok(a, b + sv), ok(a + su, b + sv));
                *quad = if ea && eb {
                    let e1 = sub(at(a + su, b), pj);
                    let e2 = sub(at(a, b + sv), pj);
                    let e12 = if dg {
                        let d = at(a + su, b + sv);
                        [d[0] - pj[0] - e1[0] - e2[0], d[1] - pj[1] - e1[1] - e2[1]]
                    } else {
                        [0.0, 0.0]
                    };
                    Quad { a: pj, e1, e2, e12 }
                } else {
                    let (fu, fv) = (su as f64, sv as f64);
                    Quad {
                        a: pj,
                        e1: [fu * ga[0], fu * ga[1]],
                        e2: [fv * gb[0], fv * gb[1]],
                        e12: [0.0, 0.0],
                    }
                };
            }
            let w = p.flux[j] / (m * m) as f64;
            let mf = m as f64;
            for kv in 0..m {
                let v = (kv as f64 + 0.5) / mf - 0.5;
                for ku in 0..m {
                    let u = (ku as f64 + 0.5) / mf - 0.5;
                    let q = &quads[(u >= 0.0) as usize | (((v >= 0.0) as usize) << 1)];
                    let (au, av) = (u.abs(), v.abs());
                    let uv = au * av;
                    let x = q.a[0] + au * q.e1[0] + av * q.e2[0] + uv * q.e12[0];
                    let y = q.a[1] + au * q.e1[1] + av * q.e2[1] + uv * q.e12[1];
                    splat(&mut out, s, x, y, w);
                }
            }
        }
    }
    (out, most, capped)
}

pub fn geometric_psf(p: &Pupil, o: &PsfOptions, d: &mut Diagnostics) -> (Vec<f64>, f64) {
    let (out, most, capped) = smooth_spot(p, o);
    d.set("geometric_subsamples_max", most as f64);
    d.set("geometric_capped_flux", capped);
    let (mut cx, mut cy, mut wsum) = (0.0, 0.0, 0.0);
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        let dx = p.image[j].x - p.chief.x;
        let dy = p.image[j].y - p.chief.y;
        cx += p.flux[j] * dx;
        cy += p.flux[j] * dy;
        wsum += p.flux[j];
    }
    let (cx, cy) = (cx / wsum, cy / wsum);
    let mut var = 0.0;
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        let dx = p.image[j].x - p.chief.x - cx;
        let dy = p.image[j].y - p.chief.y - cy;
        var += p.flux[j] * (dx * dx + dy * dy);
    }
    let rms = (var / wsum).sqrt();
    // Airy radius from the working cone: 1.22 lambda / (2 NA), NA from the ray spread.
    let (mut lmin, mut lmax) = (f64::MAX, f64::MIN);
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        lmin = lmin.min(p.l[j]);
        lmax = lmax.max(p.l[j]);
    }
    let na = 0.5 * (lmax - lmin) * p.n_image;
    let airy = if na > 0.0 {
        0.61 * p.wavelength_mm / na
    } else {
        f64::INFINITY
    };
    if rms < airy {
        d.warn(format!(
            "geometric PSF near the diffraction limit: RMS spot {:.2} um is smaller than the Airy radius {:.2} um; use method=fft or huygens",
            rms * 1e3,
            airy * 1e3
        ));
    }
    let sigma = p.rms_wavefront();
    d.set("rms_spot_um", rms * 1e3);
    d.set("airy_radius_um", airy * 1e3);
    d.set("rms_wavefront_waves", sigma);
    d.set("strehl_method", "marechal");
    let transmitted = p.transmitted_fraction();
    let window: f64 = out.iter().sum();
    d.set(
        "energy_in_window",
        if transmitted > 0.0 { window / transmitted } else { 0.0 },
    );
    (out, (-(2.0 * std::f64::consts::PI * sigma).powi(2)).exp())
}
