//! A surface of the lens (`Surface`) and its geometry: sag of a conic plus even (and odd)
//! aspheric terms, ray intersection (closed form for the conic, Newton refinement for the
//! aspheric terms) and the surface normal.

use glam::DVec3;

/// Highest even-asphere order supported: a2 .. a20.
pub const MAX_ASPHERE_TERMS: usize = 10;
/// Odd-power terms supported (OpticStudio's odd asphere): a1, a3, a5, a7.
pub const ODD_TERMS: usize = 4;

#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    /// Curvature 1/R (mm^-1); 0 for a plane.
    pub curvature: f64,
    pub conic: f64,
    /// a2, a4, ... a20: coefficient of r^(2(i+1)).
    pub aspheric: [f64; MAX_ASPHERE_TERMS],
    /// a1, a3, a5, a7: coefficient of r^(2i+1) (a1 alone is an axicon's cone; no paraxial
    /// power: a cone has no focus, an r^3 term no curvature at the vertex).
    pub odd: [f64; ODD_TERMS],
    /// Thickness to the next surface (or to the image plane for the last surface).
    pub thickness: f64,
    /// Global z of the vertex (first surface at 0).
    pub z: f64,
    /// Clear semi-diameter; None means no clipping.
    pub semi_diameter: Option<f64>,
    pub name: String,
}

impl Surface {
    pub fn has_asphere(&self) -> bool {
        self.aspheric.iter().any(|a| *a != 0.0) || self.has_odd()
    }

    pub fn has_odd(&self) -> bool {
        self.odd.iter().any(|a| *a != 0.0)
    }

    /// Aspheric terms up to the last nonzero one (the rest add nothing).
    pub fn asphere_terms(&self) -> usize {
        self.aspheric.iter().rposition(|a| *a != 0.0).map_or(0, |i| i + 1)
    }
}

/// How far below 0 the conic's 1 - (1+k) c^2 r^2 may fall (a relative rounding error) and
/// still count as the rim: a ball lens whose clear radius equals its radius of curvature
/// gives -2e-16 for some radii (R = 2.5, 5, 10) and +0 for others.
pub const RIM_TOLERANCE: f64 = 1e-12;

/// Sag z(r^2); None where the conic is undefined (1 - (1+k) c^2 r^2 < 0, beyond rounding).
#[inline]
pub fn sag(s: &Surface, rho: f64) -> Option<f64> {
    let c = s.curvature;
    let arg = 1.0 - (1.0 + s.conic) * c * c * rho;
    if arg < -RIM_TOLERANCE {
        return None;
    }
    let mut z = c * rho / (1.0 + arg.max(0.0).sqrt());
    if s.has_asphere() {
        let mut p = rho;
        for a in s.aspheric.iter() {
            z += a * p;
            p *= rho;
        }
        z += odd_sag_slope(&s.odd, rho).0;
    }
    Some(z)
}

/// Unit normal (pointing towards +z) at a point (x, y) given dz/d(rho).
#[inline]
fn normal_from_slope(x: f64, y: f64, dz: f64) -> DVec3 {
    DVec3::new(-2.0 * x * dz, -2.0 * y * dz, 1.0).normalize()
}

/// Intersect a ray (point `p` in the surface's local frame, unit direction `d`) with the
/// surface. Returns the path parameter t and the unit normal at the hit, or None when the
/// ray misses.
#[inline]
pub fn intersect(s: &Surface, p: DVec3, d: DVec3) -> Option<(f64, DVec3)> {
    let c = s.curvature;
    let (t0, ok) = conic_start(c, 1.0 + s.conic, [p.x, p.y, p.z], [d.x, d.y, d.z]);
    if !ok {
        return None;
    }
    if !s.has_asphere() {
        let h = p + t0 * d;
        let rho = h.x * h.x + h.y * h.y;
        let arg = 1.0 - (1.0 + s.conic) * c * c * rho;
        if arg < 0.0 {
            return None;
        }
        // Beyond the hemisphere of a closed conic (z on the far sheet) is a miss.
        if c != 0.0 && (1.0 - c * (1.0 + s.conic) * h.z) <= 0.0 && s.conic > -1.0 {
            return None;
        }
        let q = arg.sqrt();
        let dz = if q > 0.0 { c / (2.0 * q) } else { return None };
        return Some((t0, normal_from_slope(h.x, h.y, dz)));
    }
    // Newton on F(t) = z(t) - sag(rho(t)) from the conic's root (the lane code, one lane).
    let mut h = AsphereHits::<1>::default();
    asphere_lanes(
        s,
        s.asphere_terms(),
        &[[p.x], [p.y], [p.z]],
        &[[d.x], [d.y], [d.z]],
        &[t0],
        &[true],
        &mut h,
    );
    h.hit[0].then(|| (h.t[0], DVec3::new(h.nx[0], h.ny[0], h.nz[0])))
}

/// The base conic's (or plane's) intersection parameter along p + t d (p in the surface's
/// frame, `kk` = 1 + conic), branch free apart from the plane case: `ok` false where the
/// ray misses it (a negative discriminant, a ray parallel to a plane).
#[inline(always)]
pub(crate) fn conic_start(c: f64, kk: f64, p: [f64; 3], d: [f64; 3]) -> (f64, bool) {
    let ([px, py, pz], [dx, dy, dz]) = (p, d);
    if c == 0.0 {
        return (-pz / dz, dz != 0.0);
    }
    // Conic c(x^2 + y^2 + (1+k) z^2) - 2z = 0 along p + t d: A t^2 + 2 b t + C = 0.
    let a = c * (dx * dx + dy * dy + kk * dz * dz);
    let b = c * (px * dx + py * dy + kk * pz * dz) - dz;
    let cc = c * (px * px + py * py + kk * pz * pz) - 2.0 * pz;
    let disc = b * b - a * cc;
    // Root on the sheet through the vertex, in the form stable for c -> 0: cc / den; where
    // that lands on the far sheet (1 - (1+k) c z <= 0: a ray starting beyond the centre of
    // curvature), the other root, den / a.
    let den = -b + (-b).signum() * disc.max(0.0).sqrt();
    let t = far_sheet_other_root(c, kk, pz, dz, cc / den, den / a);
    (t, (disc >= 0.0) & (den != 0.0))
}

/// `t` unless the point it reaches lies on the far sheet of the conic (1 - (1+k) c z <= 0),
/// then `other` (the quadratic's other root).
#[inline(always)]
pub(crate) fn far_sheet_other_root(c: f64, kk: f64, pz: f64, dz: f64, t: f64, other: f64) -> f64 {
    if 1.0 - kk * c * (pz + t * dz) <= 0.0 {
        other
    } else {
        t
    }
}

/// Newton iterations allowed to an even-asphere intersection (a ray not converged by then
/// misses) and the step that counts as converged, relative to the size of the numbers
/// involved (|t| and the point's distance from the vertex, at least 1 mm): an absolute
/// 1e-13 mm is below one ulp once they pass ~1000 mm, and such rays never converged.
const NEWTON_MAX: usize = 30;
const NEWTON_TOL: f64 = 1e-13;

/// Odd terms a1 r + a3 r^3 + a5 r^5 + a7 r^7 and their derivative with respect to rho = r^2,
/// (a1 / r + 3 a3 r + 5 a5 r^3 + 7 a7 r^5) / 2. At the vertex an r^1 term (a cone's apex)
/// has no slope to speak of: the normal there is taken along the axis.
#[inline(always)]
fn odd_sag_slope(b: &[f64; ODD_TERMS], rho: f64) -> (f64, f64) {
    let r = rho.sqrt();
    let z = r * (b[0] + rho * (b[1] + rho * (b[2] + rho * b[3])));
    let inv_r = if r > 0.0 { 1.0 / r } else { 0.0 };
    let dz = 0.5 * (b[0] * inv_r + r * (3.0 * b[1] + rho * (5.0 * b[2] + rho * 7.0 * b[3])));
    (z, dz)
}

/// Sag and its derivative with respect to rho = r^2 over the first `a.len()` aspheric terms
/// (the others zero), branch free: `ok` false where the base conic is undefined there.
#[inline(always)]
fn sag_slope(c: f64, kk: f64, a: &[f64], rho: f64) -> (f64, f64, bool) {
    let arg = 1.0 - kk * c * c * rho;
    let q = arg.max(0.0).sqrt();
    let mut z = c * rho / (1.0 + q);
    let mut dz = if q > 0.0 { c / (2.0 * q) } else { f64::INFINITY };
    let mut p = 1.0;
    for (i, &ai) in a.iter().enumerate() {
        // term ai * rho^(i+1)
        dz += ai * (i as f64 + 1.0) * p;
        p *= rho;
        z += ai * p;
    }
    (z, dz, arg >= 0.0)
}

/// Even-asphere intersections of N rays, for the kernel's blocks and single rays alike.
#[derive(Clone, Copy)]
pub(crate) struct AsphereHits<const N: usize> {
    pub t: [f64; N],
    pub nx: [f64; N],
    pub ny: [f64; N],
    pub nz: [f64; N],
    pub hit: [bool; N],
}

impl<const N: usize> Default for AsphereHits<N> {
    fn default() -> Self {
        AsphereHits {
            t: [0.0; N],
            nx: [0.0; N],
            ny: [0.0; N],
            nz: [1.0; N],
            hit: [false; N],
        }
    }
}

/// Newton on F(t) = z(t) - sag(rho(t)) for N rays in lockstep (points `p` in the surface's
/// frame, unit directions `d`, starting parameters `t0`, e.g. the base conic's root): each
/// iteration updates every ray still iterating in one branch-free pass over the lanes, so
/// the loop vectorizes and the rays' latency chains overlap; a ray's arithmetic is the
/// same as alone, so a block and a single ray give the same bits. Rays not `active` (failed
/// already, padding) are skipped. `nterms`: aspheric terms up to the last nonzero one.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub(crate) fn asphere_lanes<const N: usize>(
    s: &Surface,
    nterms: usize,
    p: &[[f64; N]; 3],
    d: &[[f64; N]; 3],
    t0: &[f64; N],
    active: &[bool; N],
    out: &mut AsphereHits<N>,
) {
    let (c, kk, a) = (s.curvature, 1.0 + s.conic, &s.aspheric[..nterms]);
    let (odd, has_odd) = (&s.odd, s.has_odd());
    // sag and slope, with the odd terms where the surface has any
    let sag_slope = |c: f64, kk: f64, a: &[f64], rho: f64| {
        let (z, dz, ok) = sag_slope(c, kk, a, rho);
        if has_odd {
            let (zo, dzo) = odd_sag_slope(odd, rho);
            (z + zo, dz + dzo, ok)
        } else {
            (z, dz, ok)
        }
    };
    let ([px, py, pz], [dx, dy, dz]) = (p, d);
    let mut t = [0.0; N];
    let mut live = *active;
    let mut conv = [false; N];
    for j in 0..N {
        t[j] = if t0[j].is_finite() { t0[j] } else { -pz[j] / dz[j] };
    }
    for _ in 0..NEWTON_MAX {
        let mut any = false;
        for j in 0..N {
            let (hx, hy, hz) = (px[j] + t[j] * dx[j], py[j] + t[j] * dy[j], pz[j] + t[j] * dz[j]);
            let (z, dzr, ok) = sag_slope(c, kk, a, hx * hx + hy * hy);
            let f = hz - z;
            let fp = dz[j] - dzr * 2.0 * (hx * dx[j] + hy * dy[j]);
            let ok = ok & (fp != 0.0) & fp.is_finite();
            let step = f / fp;
            let go = live[j] & ok;
            t[j] = if go { t[j] - step } else { t[j] };
            let scale = 1.0f64.max(t[j].abs()).max(hx.abs() + hy.abs() + hz.abs());
            let done = go & (step.abs() < NEWTON_TOL * scale);
            conv[j] |= done;
            live[j] = go & !done;
            any |= live[j];
        }
        if !any {
            break;
        }
    }
    for j in 0..N {
        let (hx, hy) = (px[j] + t[j] * dx[j], py[j] + t[j] * dy[j]);
        let (_, dzr, ok) = sag_slope(c, kk, a, hx * hx + hy * hy);
        let n = normal_from_slope(hx, hy, dzr);
        let hit = conv[j] & ok & dzr.is_finite();
        out.hit[j] = hit;
        out.t[j] = if hit { t[j] } else { 0.0 };
        out.nx[j] = if hit { n.x } else { 0.0 };
        out.ny[j] = if hit { n.y } else { 0.0 };
        out.nz[j] = if hit { n.z } else { 1.0 };
    }
}

/// Vector Snell's law. `nrm` is a unit normal of either orientation. Returns None on
/// total internal reflection.
#[inline]
pub fn refract(d: DVec3, nrm: DVec3, n1: f64, n2: f64) -> Option<DVec3> {
    if n1 == n2 {
        return Some(d);
    }
    let mut nrm = nrm;
    let mut cos_i = d.dot(nrm);
    if cos_i < 0.0 {
        nrm = -nrm;
        cos_i = -cos_i;
    }
    let mu = n1 / n2;
    let k = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        return None;
    }
    Some(mu * d + (k.sqrt() - mu * cos_i) * nrm)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn surf(c: f64, k: f64, a4: f64) -> Surface {
        let mut aspheric = [0.0; MAX_ASPHERE_TERMS];
        aspheric[1] = a4;
        Surface {
            curvature: c,
            conic: k,
            aspheric,
            odd: [0.0; ODD_TERMS],
            thickness: 1.0,
            z: 0.0,
            semi_diameter: None,
            name: String::new(),
        }
    }

    #[test]
    fn hit_lies_on_the_surface() {
        for s in [
            surf(0.05, 0.0, 0.0),
            surf(-0.03, -0.7, 0.0),
            surf(0.04, 0.3, 2e-5),
            surf(0.0, 0.0, 1e-4),
        ] {
            let p = DVec3::new(1.0, -2.0, -5.0);
            let d = DVec3::new(0.05, 0.2, 1.0).normalize();
            let (t, n) = intersect(&s, p, d).unwrap();
            let h = p + t * d;
            let z = sag(&s, h.x * h.x + h.y * h.y).unwrap();
            assert!((h.z - z).abs() < 1e-12, "{} vs {}", h.z, z);
            // Normal is perpendicular to the surface: compare with a finite-difference tangent.
            let e = 1e-6;
            let zx = (sag(&s, (h.x + e).powi(2) + h.y * h.y).unwrap()
                - sag(&s, (h.x - e).powi(2) + h.y * h.y).unwrap())
                / (2.0 * e);
            assert!((n.dot(DVec3::new(1.0, 0.0, zx).normalize())).abs() < 1e-8);
        }
    }

    #[test]
    fn a_sphere_reaches_its_rim_at_r_equal_to_its_radius() {
        // 1 - c^2 R^2 rounds to -2e-16 for some R (2.5, 5, 10): still the rim, sag = R.
        for r in [1.5, 2.5, 3.0, 4.0, 5.0, 10.0, 12.7] {
            let s = surf(1.0 / r, 0.0, 0.0);
            let z = sag(&s, r * r).unwrap();
            assert!((z - r).abs() < 1e-5 * r, "R={r}: sag {z}");
            assert!(sag(&s, (r * (1.0 + 1e-9)).powi(2)).is_none());
        }
    }

    #[test]
    fn snell_law_holds() {
        let d = DVec3::new(0.0, 0.5f64.sin(), 0.5f64.cos());
        let out = refract(d, DVec3::Z, 1.0, 1.5).unwrap();
        assert!((out.y * 1.5 - d.y).abs() < 1e-15);
        assert!((out.length() - 1.0).abs() < 1e-15);
        assert!(refract(DVec3::new(0.0, 0.8, 0.6), DVec3::Z, 1.5, 1.0).is_none());
    }
}
