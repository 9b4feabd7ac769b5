//! The ray-tracing kernel: one surface at a time over a block of rays held as a struct of
//! arrays, so the compiler can vectorize the lane loop (AVX2/FMA chosen at run time).
//!
//! The same inline step functions trace a single ray (`trace::System::trace`) and a block,
//! so there is one implementation of the geometry. Lanes are computed unconditionally and a
//! ray's status only changes while it is still Ok: a failed ray keeps the status and surface
//! of its first failure, and its (meaningless) coordinates are never written out.

use crate::lens::{Lens, Surface};
use crate::surface;

/// How a ray ended: it reached the image plane, or where and why it stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Status {
    Ok = 0,
    Missed = 1,
    Clipped = 2,
    Tir = 3,
    Invalid = 4,
}

impl Status {
    /// The status for a kernel code (0-4).
    pub fn from_code(c: u8) -> Status {
        match c {
            0 => Status::Ok,
            1 => Status::Missed,
            2 => Status::Clipped,
            3 => Status::Tir,
            _ => Status::Invalid,
        }
    }
}

/// How far behind its current point a ray may meet the next surface and still count (mm):
/// rounding only, e.g. a ray that starts on the surface.
const BEHIND_TOL_MM: f64 = 1e-9;

/// Rays per block: 8 f64 arrays of 64 lanes stay well inside L1.
pub const LANES: usize = 64;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Plane,
    Sphere,
    Conic,
    Asphere,
}

/// One surface reduced to what the kernel needs at one wavelength.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SurfConst {
    pub kind: Kind,
    /// Vertex z (global).
    pub z: f64,
    pub c: f64,
    /// 1 + conic constant.
    pub kk: f64,
    /// Clear semi-diameter squared (infinite when there is none).
    pub sd2: f64,
    /// Index before the surface (for the optical path) and n_before / n_after.
    pub n1: f64,
    pub mu: f64,
    /// The indices on both sides are equal: the direction does not change.
    pub same: bool,
    /// Aspheric terms up to the last nonzero one.
    pub nterms: usize,
}

impl SurfConst {
    pub fn new(s: &Surface, n1: f64, n2: f64) -> Self {
        let kind = if s.has_asphere() {
            Kind::Asphere
        } else if s.curvature == 0.0 {
            Kind::Plane
        } else if s.conic == 0.0 {
            Kind::Sphere
        } else {
            Kind::Conic
        };
        SurfConst {
            kind,
            z: s.z,
            c: s.curvature,
            kk: 1.0 + s.conic,
            sd2: s.semi_diameter.map_or(f64::INFINITY, |d| d * d),
            n1,
            mu: n1 / n2,
            same: n1 == n2,
            nterms: s.asphere_terms(),
        }
    }
}

/// The image surface: a plane, or a sphere of curvature `c` through (0, 0, z).
#[derive(Clone, Copy, Debug)]
pub(crate) struct ImageConst {
    pub z: f64,
    pub n: f64,
    pub sd2: f64,
    pub c: f64,
}

pub(crate) fn constants(lens: &Lens, n: &[f64]) -> (Vec<SurfConst>, ImageConst) {
    let s = lens
        .surfaces
        .iter()
        .enumerate()
        .map(|(i, s)| SurfConst::new(s, n[i], n[i + 1]))
        .collect();
    let k = lens.surfaces.len();
    let sd2 = lens.image_semi_diameter.map_or(f64::INFINITY, |d| d * d);
    (
        s,
        ImageConst {
            z: lens.image_z,
            n: n[k],
            sd2,
            c: lens.image_curvature,
        },
    )
}

/// A ray's state in plain numbers.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Ray {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub dx: f64,
    pub dy: f64,
    pub dz: f64,
    pub opl: f64,
}

/// Intersection with a plane or conic (closed form) and the unit normal there, pointing
/// towards +z. Returns (t, nx, ny, nz, hit); `hit` is false for a miss, and the other values
/// are then meaningless (possibly NaN) but harmless. Branch-free apart from `KIND`, which is
/// the same for every lane.
#[inline(always)]
fn hit_conic(sc: &SurfConst, kind: Kind, r: &Ray) -> (f64, f64, f64, f64, bool) {
    let (x, y, z) = (r.x, r.y, r.z - sc.z);
    let (dx, dy, dz) = (r.dx, r.dy, r.dz);
    if kind == Kind::Plane {
        return (-z / dz, 0.0, 0.0, 1.0, dz != 0.0);
    }
    let (c, kk) = (sc.c, sc.kk);
    // Conic c(x^2 + y^2 + (1+k) z^2) - 2z = 0 along p + t d: A t^2 + 2 b t + C = 0, root on
    // the sheet through the vertex in the form that stays stable as c -> 0.
    let a = c * (dx * dx + dy * dy + kk * dz * dz);
    let b = c * (x * dx + y * dy + kk * z * dz) - dz;
    let cc = c * (x * x + y * y + kk * z * z) - 2.0 * z;
    let disc = b * b - a * cc;
    let den = -b + disc.max(0.0).sqrt().copysign(-b);
    // (The other root where this one lands on the far sheet: a ray from beyond the centre
    // of curvature.)
    let t = surface::far_sheet_other_root(c, kk, z, dz, cc / den, den / a);
    let (hx, hy, hz) = (x + t * dx, y + t * dy, z + t * dz);
    // On the conic, sqrt(1 - (1+k) c^2 r^2) = 1 - (1+k) c z; it is positive only on the
    // vertex sheet (the far sheet of a closed conic is a miss).
    let q = 1.0 - kk * c * hz;
    let hit = (disc >= 0.0) & (den != 0.0) & (q > 0.0);
    // Normal (-c x, -c y, q) has length sqrt(1 - k c^2 r^2): exactly 1 on a sphere.
    if kind == Kind::Sphere {
        (t, -c * hx, -c * hy, q, hit)
    } else {
        let n2 = c * c * (hx * hx + hy * hy) + q * q;
        let inv = 1.0 / n2.sqrt();
        (t, -c * hx * inv, -c * hy * inv, q * inv, hit)
    }
}

/// Vector Snell's law with a unit normal of either orientation; `ok` false on TIR.
#[inline(always)]
fn refract(sc: &SurfConst, r: &mut Ray, nx: f64, ny: f64, nz: f64) -> bool {
    let cos_raw = r.dx * nx + r.dy * ny + r.dz * nz;
    let s = 1.0f64.copysign(cos_raw);
    let cos_i = cos_raw * s;
    let mu = sc.mu;
    let k = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
    let g = (k.max(0.0).sqrt() - mu * cos_i) * s;
    r.dx = mu * r.dx + g * nx;
    r.dy = mu * r.dy + g * ny;
    r.dz = mu * r.dz + g * nz;
    k >= 0.0
}

/// Status code of a ray after one surface, in the order the checks apply (written as
/// selects, not branches, so lane loops vectorize).
#[inline(always)]
fn verdict(hit: bool, inside: bool, no_tir: bool) -> u8 {
    let st = if no_tir { Status::Ok as u8 } else { Status::Tir as u8 };
    let st = if inside { st } else { Status::Clipped as u8 };
    if hit {
        st
    } else {
        Status::Missed as u8
    }
}

/// One surface on one ray: intersect, clip, and refract when `refract` (false where the
/// trace stops at this surface or the index does not change).
#[inline(always)]
pub(crate) fn step(sc: &SurfConst, s: &Surface, kind: Kind, r: &mut Ray, clip: bool, refract_here: bool) -> u8 {
    let hit = if kind == Kind::Asphere {
        asphere_hit(sc, s, r)
    } else {
        hit_conic(sc, kind, r)
    };
    step_with(sc, hit, r, clip, refract_here)
}

/// [`step`] given the intersection (t, normal, hit).
#[inline(always)]
fn step_with(
    sc: &SurfConst,
    (t, nx, ny, nz, hit): (f64, f64, f64, f64, bool),
    r: &mut Ray,
    clip: bool,
    refract_here: bool,
) -> u8 {
    // A surface met behind the ray (it would have had to cross it already) is a miss.
    let hit = hit & (t >= -BEHIND_TOL_MM);
    r.x += t * r.dx;
    r.y += t * r.dy;
    r.z += t * r.dz;
    r.opl += sc.n1 * t;
    let inside = !clip | (r.x * r.x + r.y * r.y <= sc.sd2);
    let no_tir = if refract_here { refract(sc, r, nx, ny, nz) } else { true };
    verdict(hit, inside, no_tir)
}

/// Even asphere on one ray: the block's lane code on one lane (surface::intersect).
#[inline(never)]
fn asphere_hit(sc: &SurfConst, s: &Surface, r: &Ray) -> (f64, f64, f64, f64, bool) {
    let p = glam::DVec3::new(r.x, r.y, r.z - sc.z);
    match surface::intersect(s, p, glam::DVec3::new(r.dx, r.dy, r.dz)) {
        Some((t, n)) => (t, n.x, n.y, n.z, true),
        None => (0.0, 0.0, 0.0, 1.0, false),
    }
}

/// Even asphere over a block: Newton in lockstep over the lanes still Ok (surface.rs).
#[inline(always)]
fn asphere_block(b: &Block, sc: &SurfConst, s: &Surface) -> surface::AsphereHits<LANES> {
    let (mut p, mut d) = ([[0.0; LANES]; 3], [[0.0; LANES]; 3]);
    let (mut t0, mut active) = ([0.0; LANES], [false; LANES]);
    for j in 0..LANES {
        let (pj, dj) = ([b.x[j], b.y[j], b.z[j] - sc.z], [b.dx[j], b.dy[j], b.dz[j]]);
        let (t, ok) = surface::conic_start(sc.c, sc.kk, pj, dj);
        for k in 0..3 {
            p[k][j] = pj[k];
            d[k][j] = dj[k];
        }
        t0[j] = t;
        active[j] = ok & (b.status[j] == 0);
    }
    let mut h = surface::AsphereHits::default();
    surface::asphere_lanes(s, sc.nterms, &p, &d, &t0, &active, &mut h);
    h
}

/// The image plane on one ray.
#[inline(always)]
pub(crate) fn step_image(im: &ImageConst, r: &mut Ray, clip: bool) -> u8 {
    let (t, hit) = if im.c == 0.0 {
        ((im.z - r.z) / r.dz, r.dz > 0.0)
    } else {
        // A curved sensor: the sphere's sheet through the vertex, met going forward.
        let sc = SurfConst {
            kind: Kind::Sphere,
            z: im.z,
            c: im.c,
            kk: 1.0,
            sd2: im.sd2,
            n1: im.n,
            mu: 1.0,
            same: true,
            nterms: 0,
        };
        let (t, _, _, _, hit) = hit_conic(&sc, Kind::Sphere, r);
        (t, hit & (r.dz > 0.0) & (t >= -BEHIND_TOL_MM))
    };
    r.x += t * r.dx;
    r.y += t * r.dy;
    r.z += t * r.dz;
    r.opl += im.n * t;
    let inside = !clip | (r.x * r.x + r.y * r.y <= im.sd2);
    verdict(hit, inside, true)
}

/// Whether a launched ray is usable: finite, with a unit direction.
#[inline(always)]
pub(crate) fn valid_input(r: &Ray) -> bool {
    let n2 = r.dx * r.dx + r.dy * r.dy + r.dz * r.dz;
    [r.x, r.y, r.z, r.dx, r.dy, r.dz].iter().all(|v| v.is_finite()) && (n2 - 1.0).abs() <= 1e-9
}

/// A block of rays as a struct of arrays. Lanes past `len` are padding.
#[derive(Clone)]
pub struct Block {
    pub x: [f64; LANES],
    pub y: [f64; LANES],
    pub z: [f64; LANES],
    pub dx: [f64; LANES],
    pub dy: [f64; LANES],
    pub dz: [f64; LANES],
    pub opl: [f64; LANES],
    pub status: [u8; LANES],
    /// Surface (0-based; surfaces.len() = image plane) of the first failure, or -1.
    pub surface: [i32; LANES],
    pub len: usize,
}

impl Default for Block {
    fn default() -> Self {
        Block {
            x: [0.0; LANES],
            y: [0.0; LANES],
            z: [0.0; LANES],
            dx: [0.0; LANES],
            dy: [0.0; LANES],
            dz: [1.0; LANES],
            opl: [0.0; LANES],
            status: [Status::Invalid as u8; LANES],
            surface: [0; LANES],
            len: 0,
        }
    }
}

impl Block {
    /// Prepare for `len` rays: the loader sets lanes `0..len` (`set`), the lanes after are
    /// padding, marked Invalid so that nothing is reported for them.
    #[inline]
    pub fn reset(&mut self, len: usize) {
        self.len = len;
        self.status[len..].fill(Status::Invalid as u8);
    }

    #[inline(always)]
    pub(crate) fn get(&self, j: usize) -> Ray {
        Ray {
            x: self.x[j],
            y: self.y[j],
            z: self.z[j],
            dx: self.dx[j],
            dy: self.dy[j],
            dz: self.dz[j],
            opl: self.opl[j],
        }
    }
    #[inline(always)]
    pub(crate) fn put(&mut self, j: usize, r: &Ray) {
        self.x[j] = r.x;
        self.y[j] = r.y;
        self.z[j] = r.z;
        self.dx[j] = r.dx;
        self.dy[j] = r.dy;
        self.dz[j] = r.dz;
        self.opl[j] = r.opl;
    }
    /// A lane's verdict at surface `surface`: only a ray still Ok takes it (as selects, so
    /// lane loops stay branch-free), so a failed ray keeps its first failure.
    #[inline(always)]
    fn record(&mut self, j: usize, st: u8, surface: i32) {
        let alive = self.status[j] == 0;
        self.surface[j] = if alive & (st != 0) { surface } else { self.surface[j] };
        self.status[j] = if alive { st } else { self.status[j] };
    }

    /// Set lane `j` to a ray starting at (x, y, z) along unit (dx, dy, dz), and mark it
    /// Ok or Invalid.
    #[inline(always)]
    pub fn set(&mut self, j: usize, p: [f64; 3], d: [f64; 3]) {
        let r = Ray {
            x: p[0],
            y: p[1],
            z: p[2],
            dx: d[0],
            dy: d[1],
            dz: d[2],
            opl: 0.0,
        };
        let ok = valid_input(&r);
        self.put(j, &r);
        self.status[j] = if ok { Status::Ok as u8 } else { Status::Invalid as u8 };
        self.surface[j] = if ok { -1 } else { 0 };
    }
}

/// Surfaces [0, last) of a lens, the image plane unless the trace stops at a surface.
pub(crate) struct Plan<'a> {
    pub consts: &'a [SurfConst],
    pub surfaces: &'a [Surface],
    pub image: &'a ImageConst,
    /// Stop at the intersection with this surface, before refracting there.
    pub stop_at: Option<usize>,
    pub clip: bool,
}

impl Plan<'_> {
    /// Surfaces traced: all of them, or up to and including `stop_at`.
    pub fn last(&self) -> usize {
        self.stop_at.map_or(self.consts.len(), |i| i + 1)
    }

    /// Whether the ray refracts at surface `i` (not where the trace stops, nor between
    /// equal indices).
    pub fn refracts(&self, i: usize) -> bool {
        self.stop_at != Some(i) && !self.consts[i].same
    }
}

/// One surface over all lanes. Every choice that is the same for all lanes is a constant
/// here, so the loop body is branch-free and vectorizes.
#[inline(always)]
fn lanes<const KIND: u8, const CLIP: bool, const REFRACT: bool>(b: &mut Block, i: usize, sc: &SurfConst, s: &Surface) {
    let kind = match KIND {
        0 => Kind::Plane,
        1 => Kind::Sphere,
        2 => Kind::Conic,
        _ => Kind::Asphere,
    };
    if kind == Kind::Asphere {
        let h = asphere_block(b, sc, s);
        for j in 0..LANES {
            let mut r = b.get(j);
            let st = step_with(sc, (h.t[j], h.nx[j], h.ny[j], h.nz[j], h.hit[j]), &mut r, CLIP, REFRACT);
            b.put(j, &r);
            b.record(j, st, i as i32);
        }
        return;
    }
    for j in 0..LANES {
        let mut r = b.get(j);
        let st = step(sc, s, kind, &mut r, CLIP, REFRACT);
        b.put(j, &r);
        b.record(j, st, i as i32);
    }
}

#[inline(always)]
fn surface_lanes<const KIND: u8>(b: &mut Block, i: usize, sc: &SurfConst, s: &Surface, clip: bool, refract: bool) {
    match (clip, refract) {
        (true, true) => lanes::<KIND, true, true>(b, i, sc, s),
        (true, false) => lanes::<KIND, true, false>(b, i, sc, s),
        (false, true) => lanes::<KIND, false, true>(b, i, sc, s),
        (false, false) => lanes::<KIND, false, false>(b, i, sc, s),
    }
}

#[inline(always)]
fn image_lanes<const CLIP: bool>(b: &mut Block, k: i32, im: &ImageConst) {
    for j in 0..LANES {
        let mut r = b.get(j);
        let st = step_image(im, &mut r, CLIP);
        b.put(j, &r);
        b.record(j, st, k);
    }
}

#[inline(always)]
fn run_inline(plan: &Plan, b: &mut Block) {
    for i in 0..plan.last() {
        let (sc, s) = (&plan.consts[i], &plan.surfaces[i]);
        let refract = plan.refracts(i);
        match sc.kind {
            Kind::Plane => surface_lanes::<0>(b, i, sc, s, plan.clip, refract),
            Kind::Sphere => surface_lanes::<1>(b, i, sc, s, plan.clip, refract),
            Kind::Conic => surface_lanes::<2>(b, i, sc, s, plan.clip, refract),
            Kind::Asphere => surface_lanes::<3>(b, i, sc, s, plan.clip, refract),
        }
    }
    if plan.stop_at.is_none() {
        let k = plan.consts.len() as i32;
        if plan.clip {
            image_lanes::<true>(b, k, plan.image)
        } else {
            image_lanes::<false>(b, k, plan.image)
        }
    }
}

// The same kernel compiled for wider vector units, chosen once at run time. Rust does not
// fuse multiplies and adds on its own, so every variant gives bit-identical results.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_avx2(plan: &Plan, b: &mut Block) {
    run_inline(plan, b)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx2,fma")]
unsafe fn run_avx512(plan: &Plan, b: &mut Block) {
    run_inline(plan, b)
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Simd {
    Avx512,
    Avx2,
    Baseline,
}

/// The vector instruction set the kernel uses on this CPU.
pub fn simd_level() -> Simd {
    static LEVEL: std::sync::OnceLock<Simd> = std::sync::OnceLock::new();
    *LEVEL.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx512f") && has!("avx512vl") && has!("avx512dq") && has!("avx2") && has!("fma") {
                return Simd::Avx512;
            }
            if has!("avx2") && has!("fma") {
                return Simd::Avx2;
            }
        }
        Simd::Baseline
    })
}

/// Trace every lane of a block through the plan (vectorized where the CPU allows).
pub(crate) fn run(plan: &Plan, b: &mut Block) {
    match simd_level() {
        // SAFETY: simd_level() checked that the CPU has these features.
        #[cfg(target_arch = "x86_64")]
        Simd::Avx512 => unsafe { run_avx512(plan, b) },
        #[cfg(target_arch = "x86_64")]
        Simd::Avx2 => unsafe { run_avx2(plan, b) },
        _ => run_inline(plan, b),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every compiled variant the CPU can run gives the same bits as the baseline.
    #[test]
    fn simd_variants_agree_bit_for_bit() {
        let lens = Lens::from_json(
            r#"{"aperture": {"type": "epd", "value": 10}, "wavelengths_nm": [550],
                "surfaces": [
                  {"radius": 12, "conic": -0.6, "aspheric": {"a4": -2e-5}, "thickness": 6, "material": {"n": 1.9}, "semi_diameter": 8},
                  {"radius": "inf", "thickness": 2, "material": "air", "semi_diameter": 8},
                  {"radius": 25, "conic": 0.5, "thickness": 3, "material": {"n": 1.6}, "stop": true},
                  {"radius": -40, "thickness": 35, "material": "air", "semi_diameter": 7}]}"#,
        )
        .unwrap();
        let n = lens.indices(550.0).unwrap();
        let (consts, image) = constants(&lens, &n);
        let plan = Plan {
            consts: &consts,
            surfaces: &lens.surfaces,
            image: &image,
            stop_at: None,
            clip: true,
        };
        let mut base = Block {
            len: LANES,
            ..Block::default()
        };
        for j in 0..LANES {
            let a = (j as f64 / LANES as f64 - 0.5) * 1.6;
            base.set(
                j,
                [0.3 * j as f64 % 9.0 - 4.5, (j as f64 * 0.77) % 11.0 - 5.5, -3.0],
                [
                    0.1 * a.sin(),
                    a.sin(),
                    (1.0 - 0.01 * a.sin().powi(2) - a.sin().powi(2)).sqrt(),
                ],
            );
        }
        let mut expect = base.clone();
        run_inline(&plan, &mut expect);
        assert!(expect.status.contains(&0) && expect.status.iter().any(|&s| s != 0));
        let mut variants: Vec<(&str, Block)> = vec![];
        #[cfg(target_arch = "x86_64")]
        {
            if simd_level() != Simd::Baseline {
                let mut b = base.clone();
                unsafe { run_avx2(&plan, &mut b) };
                variants.push(("avx2", b));
            }
            if simd_level() == Simd::Avx512 {
                let mut b = base.clone();
                unsafe { run_avx512(&plan, &mut b) };
                variants.push(("avx512", b));
            }
        }
        for (name, b) in variants {
            for j in 0..LANES {
                assert_eq!(
                    (b.status[j], b.surface[j]),
                    (expect.status[j], expect.surface[j]),
                    "{name} lane {j}"
                );
                if b.status[j] == 0 {
                    let (r, e) = (b.get(j), expect.get(j));
                    assert_eq!(
                        [r.x, r.y, r.z, r.dx, r.dy, r.dz, r.opl],
                        [e.x, e.y, e.z, e.dx, e.dy, e.dz, e.opl],
                        "{name} lane {j}"
                    );
                }
            }
        }
    }
}
