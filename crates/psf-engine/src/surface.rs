//! Surface geometry: sag of a conic plus even asphere, ray intersection (closed form for
//! the conic, Newton refinement for the aspheric terms) and the surface normal.

use crate::lens::Surface;
use glam::DVec3;

/// Sag z(r^2); None where the conic is undefined (1 - (1+k) c^2 r^2 < 0).
#[inline]
pub fn sag(s: &Surface, rho: f64) -> Option<f64> {
    let c = s.curvature;
    let arg = 1.0 - (1.0 + s.conic) * c * c * rho;
    if arg < 0.0 {
        return None;
    }
    let mut z = c * rho / (1.0 + arg.sqrt());
    if s.has_asphere() {
        let mut p = rho;
        for a in s.aspheric.iter() {
            z += a * p;
            p *= rho;
        }
    }
    Some(z)
}

/// Sag and its derivative with respect to rho = r^2.
#[inline]
fn sag_and_slope(s: &Surface, rho: f64) -> Option<(f64, f64)> {
    let c = s.curvature;
    let arg = 1.0 - (1.0 + s.conic) * c * c * rho;
    if arg < 0.0 {
        return None;
    }
    let q = arg.sqrt();
    let mut z = c * rho / (1.0 + q);
    let mut dz = if q > 0.0 { c / (2.0 * q) } else { f64::INFINITY };
    let mut p = 1.0;
    for (i, a) in s.aspheric.iter().enumerate() {
        // term a * rho^(i+1)
        dz += a * (i as f64 + 1.0) * p;
        p *= rho;
        z += a * p;
    }
    Some((z, dz))
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
    let t0 = if c == 0.0 {
        if d.z == 0.0 {
            return None;
        }
        -p.z / d.z
    } else {
        // Conic c(x^2 + y^2 + (1+k) z^2) - 2z = 0 along p + t d: A t^2 + 2 b t + C = 0.
        let kk = 1.0 + s.conic;
        let a = c * (d.x * d.x + d.y * d.y + kk * d.z * d.z);
        let b = c * (p.x * d.x + p.y * d.y + kk * p.z * d.z) - d.z;
        let cc = c * (p.x * p.x + p.y * p.y + kk * p.z * p.z) - 2.0 * p.z;
        let disc = b * b - a * cc;
        if disc < 0.0 {
            return None;
        }
        // Root on the sheet through the vertex, in the form stable for c -> 0.
        let den = -b + (-b).signum() * disc.sqrt();
        if den == 0.0 {
            return None;
        }
        cc / den
    };
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
    // Newton on F(t) = z(t) - sag(rho(t)) from the conic's root.
    let mut t = if t0.is_finite() { t0 } else { -p.z / d.z };
    for _ in 0..30 {
        let h = p + t * d;
        let rho = h.x * h.x + h.y * h.y;
        let (z, dz) = sag_and_slope(s, rho)?;
        let f = h.z - z;
        let fp = d.z - dz * 2.0 * (h.x * d.x + h.y * d.y);
        if fp == 0.0 || !fp.is_finite() {
            return None;
        }
        let step = f / fp;
        t -= step;
        if step.abs() < 1e-13 {
            let h = p + t * d;
            let (_, dz) = sag_and_slope(s, h.x * h.x + h.y * h.y)?;
            if !dz.is_finite() {
                return None;
            }
            return Some((t, normal_from_slope(h.x, h.y, dz)));
        }
    }
    None
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
        let mut aspheric = [0.0; crate::lens::MAX_ASPHERE_TERMS];
        aspheric[1] = a4;
        Surface { curvature: c, conic: k, aspheric, thickness: 1.0, z: 0.0, semi_diameter: None, name: String::new() }
    }

    #[test]
    fn hit_lies_on_the_surface() {
        for s in [surf(0.05, 0.0, 0.0), surf(-0.03, -0.7, 0.0), surf(0.04, 0.3, 2e-5), surf(0.0, 0.0, 1e-4)] {
            let p = DVec3::new(1.0, -2.0, -5.0);
            let d = DVec3::new(0.05, 0.2, 1.0).normalize();
            let (t, n) = intersect(&s, p, d).unwrap();
            let h = p + t * d;
            let z = sag(&s, h.x * h.x + h.y * h.y).unwrap();
            assert!((h.z - z).abs() < 1e-12, "{} vs {}", h.z, z);
            // Normal is perpendicular to the surface: compare with a finite-difference tangent.
            let e = 1e-6;
            let zx = (sag(&s, (h.x + e).powi(2) + h.y * h.y).unwrap() - sag(&s, (h.x - e).powi(2) + h.y * h.y).unwrap()) / (2.0 * e);
            assert!((n.dot(DVec3::new(1.0, 0.0, zx).normalize())).abs() < 1e-8);
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
