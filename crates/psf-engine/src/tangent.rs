//! Forward-mode tangents of a real ray trace with respect to the lens's surface parameters:
//! the first stage of the one-pass gradient (docs/optics-in-the-loop.md, "The one-pass
//! gradient"), where a few rays carry one tangent per lens parameter.
//!
//! The ray itself is traced by the f64 kernel (`System::trace`): its status and its values
//! are the kernel's. The tangents follow the same steps in dual numbers ([`Dual`]): the base
//! conic's closed-form root, the even asphere's root by one Newton step in dual numbers from
//! the kernel's converged root (at a root F(t) = 0 the step leaves the value and gives
//! dt = -dF/dtheta / F'(t): the implicit-function theorem), the surface normal, Snell's law
//! and the optical path. The refractive indices are held fixed (a glass is not a parameter
//! here); the launch (origin and direction) is given, so aiming is the caller's.

use crate::lens::{Lens, Surface, ODD_TERMS};
use crate::trace::{End, System};
use glam::DVec3;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// A value and its derivatives along N directions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<const N: usize> {
    pub v: f64,
    pub d: [f64; N],
}

impl<const N: usize> Dual<N> {
    pub fn constant(v: f64) -> Self {
        Dual { v, d: [0.0; N] }
    }

    /// The variable of direction `k`.
    pub fn variable(v: f64, k: usize) -> Self {
        let mut d = [0.0; N];
        d[k] = 1.0;
        Dual { v, d }
    }

    fn chain(self, v: f64, dv: f64) -> Self {
        Dual {
            v,
            d: self.d.map(|x| x * dv),
        }
    }

    pub fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        self.chain(r, 0.5 / r)
    }
}

impl<const N: usize> Add for Dual<N> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a += b);
        Dual { v: self.v + o.v, d }
    }
}

impl<const N: usize> Sub for Dual<N> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        self + (-o)
    }
}

impl<const N: usize> Neg for Dual<N> {
    type Output = Self;
    fn neg(self) -> Self {
        Dual {
            v: -self.v,
            d: self.d.map(|x| -x),
        }
    }
}

// The product and quotient rules (clippy reads their + and - as suspicious).
#[allow(clippy::suspicious_arithmetic_impl)]
impl<const N: usize> Mul for Dual<N> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a = *a * o.v + self.v * b);
        Dual { v: self.v * o.v, d }
    }
}

#[allow(clippy::suspicious_arithmetic_impl)]
impl<const N: usize> Div for Dual<N> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let q = self.v / o.v;
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a = (*a - q * b) / o.v);
        Dual { v: q, d }
    }
}

impl<const N: usize> Add<f64> for Dual<N> {
    type Output = Self;
    fn add(self, o: f64) -> Self {
        Dual {
            v: self.v + o,
            d: self.d,
        }
    }
}

impl<const N: usize> Sub<f64> for Dual<N> {
    type Output = Self;
    fn sub(self, o: f64) -> Self {
        Dual {
            v: self.v - o,
            d: self.d,
        }
    }
}

impl<const N: usize> Mul<f64> for Dual<N> {
    type Output = Self;
    fn mul(self, o: f64) -> Self {
        Dual {
            v: self.v * o,
            d: self.d.map(|x| x * o),
        }
    }
}

/// A lens parameter a tangent is taken along.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    /// Curvature 1/R of a surface (mm^-1).
    Curvature(usize),
    /// Radius R of a curved surface (mm): the curvature's tangent times dc/dR = -c^2 (the
    /// design spaces' `radius` parameters).
    Radius(usize),
    /// Conic constant of a surface.
    Conic(usize),
    /// Even aspheric coefficient `k` of a surface (of r^(2(k+1)): 0 is a2, 1 is a4, ...).
    Aspheric(usize, usize),
    /// Thickness after a surface (mm): every later vertex and the image plane move with it.
    Thickness(usize),
    /// The aperture's value where it is given as an f-number (EPD = EFL / F) or as the
    /// entrance pupil's diameter (mm).
    FNumber,
    Epd,
}

impl Param {
    /// The surface it belongs to (None: the aperture's).
    fn surface(&self) -> Option<usize> {
        match *self {
            Param::Curvature(i) | Param::Radius(i) | Param::Conic(i) | Param::Aspheric(i, _) | Param::Thickness(i) => {
                Some(i)
            }
            Param::FNumber | Param::Epd => None,
        }
    }
}

/// `lens` with `p` moved by `h` (vertices and the image plane re-placed after a thickness):
/// what a tangent along `p` is the derivative of. None where `p` names no such parameter.
pub fn perturbed(lens: &Lens, p: Param, h: f64) -> Option<Lens> {
    use crate::lens::Aperture;
    let mut l = lens.clone();
    match (p, &mut l.aperture) {
        (Param::FNumber, Aperture::FNumber(f)) | (Param::Epd, Aperture::Epd(f)) => *f += h,
        (Param::FNumber | Param::Epd, _) => return None,
        _ => {
            let s = l.surfaces.get_mut(p.surface()?)?;
            match p {
                Param::Curvature(_) => s.curvature += h,
                Param::Radius(_) => s.curvature = 1.0 / (1.0 / s.curvature + h),
                Param::Conic(_) => s.conic += h,
                Param::Aspheric(_, k) => *s.aspheric.get_mut(k)? += h,
                Param::Thickness(_) => s.thickness += h,
                Param::FNumber | Param::Epd => unreachable!("matched above"),
            }
        }
    }
    let mut z = 0.0;
    for s in l.surfaces.iter_mut() {
        s.z = z;
        z += s.thickness;
    }
    l.image_z = z;
    Some(l)
}

/// A surface's shape and vertex in dual numbers.
struct DualSurface<const N: usize> {
    c: Dual<N>,
    kk: Dual<N>,
    a: Vec<Dual<N>>,
    odd: [f64; ODD_TERMS],
    z: Dual<N>,
}

/// A lens's surfaces and image plane in dual numbers, seeded along `params`.
struct DualLens<const N: usize> {
    surfs: Vec<DualSurface<N>>,
    image_z: Dual<N>,
}

/// `v` with tangent `slope(p)` along each of `params` that moves it (None: not at all).
fn seeded<const N: usize>(v: f64, params: &[Param], slope: impl Fn(Param) -> Option<f64>) -> Dual<N> {
    let mut x = Dual::constant(v);
    for (k, &p) in params.iter().enumerate() {
        if let Some(s) = slope(p) {
            x.d[k] = s;
        }
    }
    x
}

/// One along `want`, 0 along every other parameter.
fn along(want: Param) -> impl Fn(Param) -> Option<f64> {
    move |p| (p == want).then_some(1.0)
}

fn dual_lens<const N: usize>(lens: &Lens, params: &[Param]) -> DualLens<N> {
    let mut z = Dual::<N>::constant(0.0);
    let mut surfs = Vec::with_capacity(lens.surfaces.len());
    for (i, s) in lens.surfaces.iter().enumerate() {
        let nterms = s.asphere_terms().max(
            params
                .iter()
                .filter_map(|p| match *p {
                    Param::Aspheric(j, k) if j == i => Some(k + 1),
                    _ => None,
                })
                .max()
                .unwrap_or(0),
        );
        let c = s.curvature;
        surfs.push(DualSurface {
            // dc/dR = -1/R^2 = -c^2
            c: seeded(c, params, |p| match p {
                Param::Curvature(j) if j == i => Some(1.0),
                Param::Radius(j) if j == i => Some(-c * c),
                _ => None,
            }),
            kk: seeded(1.0 + s.conic, params, along(Param::Conic(i))),
            a: (0..nterms)
                .map(|k| seeded(s.aspheric[k], params, along(Param::Aspheric(i, k))))
                .collect(),
            odd: s.odd,
            z,
        });
        z = z + seeded(s.thickness, params, along(Param::Thickness(i)));
    }
    DualLens { surfs, image_z: z }
}

/// A traced ray's image point, direction and optical path with their tangents.
#[derive(Clone, Copy, Debug)]
pub struct RayTangents<const N: usize> {
    pub p: [Dual<N>; 3],
    pub d: [Dual<N>; 3],
    pub opl: Dual<N>,
}

fn dot<const N: usize>(a: &[Dual<N>; 3], b: &[Dual<N>; 3]) -> Dual<N> {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Sag and d(sag)/d(rho) of a dual surface at dual rho (the even terms and, with constant
/// coefficients, the odd ones: surface.rs's arithmetic).
fn sag_slope<const N: usize>(s: &DualSurface<N>, rho: Dual<N>) -> (Dual<N>, Dual<N>) {
    let q = (-(s.kk * s.c * s.c * rho) + 1.0).sqrt();
    let mut z = s.c * rho / (q + 1.0);
    let mut dz = s.c / (q * 2.0);
    let mut p = Dual::constant(1.0);
    for (i, &ai) in s.a.iter().enumerate() {
        dz = dz + ai * p * (i as f64 + 1.0);
        p = p * rho;
        z = z + ai * p;
    }
    if s.odd.iter().any(|b| *b != 0.0) {
        let b = s.odd;
        let r = rho.sqrt();
        let poly = ((rho * b[3] + b[2]) * rho + b[1]) * rho + b[0];
        z = z + r * poly;
        let inner = (rho * (7.0 * b[3]) + 5.0 * b[2]) * rho + 3.0 * b[1];
        // at the vertex an r^1 term has no slope to speak of (surface.rs)
        let inv_r = if r.v > 0.0 {
            Dual::constant(1.0) / r
        } else {
            Dual::constant(0.0)
        };
        dz = dz + (inv_r * b[0] + r * inner) * 0.5;
    }
    (z, dz)
}

/// The tangents of one ray traced from `p` along unit `d` (global frame, object space) to the
/// image, along `params` (at most N; unused directions stay zero). None where the kernel's
/// own trace of the ray does not reach the image (its status says why: `System::trace`).
pub fn trace_tangents<const N: usize>(sys: &System, params: &[Param], p: DVec3, d: DVec3) -> Option<RayTangents<N>> {
    let k = Dual::<N>::constant;
    trace_from(sys, params, [k(p.x), k(p.y), k(p.z)], [k(d.x), k(d.y), k(d.z)])
}

/// [`trace_tangents`] from a launch that itself moves with the parameters (the aiming's).
pub fn trace_from<const N: usize>(
    sys: &System,
    params: &[Param],
    p: [Dual<N>; 3],
    d: [Dual<N>; 3],
) -> Option<RayTangents<N>> {
    assert!(
        params.len() <= N,
        "{} parameters for {N} tangent directions",
        params.len()
    );
    trace_dual(sys, &dual_lens(sys.lens, params), p, d)
}

/// [`trace_from`] through a lens already in dual numbers (the same for every ray of a call).
fn trace_dual<const N: usize>(
    sys: &System,
    dl: &DualLens<N>,
    p: [Dual<N>; 3],
    d: [Dual<N>; 3],
) -> Option<RayTangents<N>> {
    let real = |x: &[Dual<N>; 3]| DVec3::new(x[0].v, x[1].v, x[2].v);
    if !sys.trace(real(&p), real(&d), End::Image).ok() {
        return None;
    }
    let lens = sys.lens;
    let (surfs, image_z) = (&dl.surfs, dl.image_z);
    let k = Dual::<N>::constant;
    let (mut pos, mut dir) = (p, d);
    let mut opl = k(0.0);
    for (i, (s, ds)) in lens.surfaces.iter().zip(surfs).enumerate() {
        let local = [pos[0], pos[1], pos[2] - ds.z];
        let (t, normal) = if s.has_asphere() || ds.a.iter().any(|a| a.d.iter().any(|x| *x != 0.0)) {
            asphere_hit(s, ds, &local, &dir)?
        } else {
            conic_hit(ds, &local, &dir)
        };
        for j in 0..3 {
            pos[j] = pos[j] + t * dir[j];
        }
        opl = opl + t * sys.n[i];
        let (n1, n2) = (sys.n[i], sys.n[i + 1]);
        if n1 != n2 {
            dir = refract(&dir, &normal, n1 / n2);
        }
    }
    // The image plane (a curved sensor: its sphere through the vertex, not a parameter).
    let t = if lens.image_curvature == 0.0 {
        (image_z - pos[2]) / dir[2]
    } else {
        let img = DualSurface {
            c: k(lens.image_curvature),
            kk: k(1.0),
            a: vec![],
            odd: [0.0; ODD_TERMS],
            z: image_z,
        };
        conic_hit(&img, &[pos[0], pos[1], pos[2] - image_z], &dir).0
    };
    for j in 0..3 {
        pos[j] = pos[j] + t * dir[j];
    }
    opl = opl + t * *sys.n.last().unwrap();
    Some(RayTangents { p: pos, d: dir, opl })
}

/// The base conic's root on the vertex sheet (the kernel's stable form and sheet choice) and
/// the unit normal there.
fn conic_hit<const N: usize>(s: &DualSurface<N>, p: &[Dual<N>; 3], d: &[Dual<N>; 3]) -> (Dual<N>, [Dual<N>; 3]) {
    let (c, kk) = (s.c, s.kk);
    let a = c * (d[0] * d[0] + d[1] * d[1] + kk * d[2] * d[2]);
    let b = c * (p[0] * d[0] + p[1] * d[1] + kk * p[2] * d[2]) - d[2];
    let cc = c * (p[0] * p[0] + p[1] * p[1] + kk * p[2] * p[2]) - p[2] * 2.0;
    let disc = b * b - a * cc;
    let root = if disc.v > 0.0 { disc.sqrt() } else { Dual::constant(0.0) };
    let den = -b + if -b.v >= 0.0 { root } else { -root };
    let near = cc / den;
    let t = if (-(kk * c * (p[2] + near * d[2])) + 1.0).v <= 0.0 {
        den / a
    } else {
        near
    };
    let h = [p[0] + t * d[0], p[1] + t * d[1], p[2] + t * d[2]];
    // normal (-c x, -c y, 1 - (1+k) c z), normalized
    let q = -(kk * c * h[2]) + 1.0;
    let n = [-(c * h[0]), -(c * h[1]), q];
    let len = dot(&n, &n).sqrt();
    (t, [n[0] / len, n[1] / len, n[2] / len])
}

/// An even asphere: the kernel's converged root, then one Newton step in dual numbers; the
/// normal from the dual slope.
fn asphere_hit<const N: usize>(
    s: &Surface,
    ds: &DualSurface<N>,
    p: &[Dual<N>; 3],
    d: &[Dual<N>; 3],
) -> Option<(Dual<N>, [Dual<N>; 3])> {
    let real = |x: &[Dual<N>; 3]| DVec3::new(x[0].v, x[1].v, x[2].v);
    let (t0, _) = crate::surface::intersect(s, real(p), real(d))?;
    let t0 = Dual::constant(t0);
    let h = [p[0] + t0 * d[0], p[1] + t0 * d[1], p[2] + t0 * d[2]];
    let rho = h[0] * h[0] + h[1] * h[1];
    let (z, dz) = sag_slope(ds, rho);
    let f = h[2] - z;
    let fp = d[2] - dz * (h[0] * d[0] + h[1] * d[1]) * 2.0;
    let t = t0 - f / fp;
    let h = [p[0] + t * d[0], p[1] + t * d[1], p[2] + t * d[2]];
    let (_, dz) = sag_slope(ds, h[0] * h[0] + h[1] * h[1]);
    let n = [-(h[0] * dz * 2.0), -(h[1] * dz * 2.0), Dual::constant(1.0)];
    let len = dot(&n, &n).sqrt();
    Some((t, [n[0] / len, n[1] / len, n[2] / len]))
}

/// Vector Snell's law (the kernel's form, a unit normal of either orientation).
fn refract<const N: usize>(d: &[Dual<N>; 3], n: &[Dual<N>; 3], mu: f64) -> [Dual<N>; 3] {
    let cos_raw = dot(d, n);
    let s = 1.0f64.copysign(cos_raw.v);
    let cos_i = cos_raw * s;
    let k = -((-(cos_i * cos_i) + 1.0) * (mu * mu)) + 1.0;
    let g = (k.sqrt() - cos_i * mu) * s;
    [d[0] * mu + g * n[0], d[1] * mu + g * n[1], d[2] * mu + g * n[2]]
}

/// First-order data with tangents: what paraxial aiming and the reference sphere need
/// (paraxial.rs's y-nu trace in dual numbers; an even asphere's paraxial curvature is
/// c + 2 a2, the pupils at the lens's primary wavelength). An object at infinity.
#[derive(Clone, Copy, Debug)]
pub struct ParaxialTangents<const N: usize> {
    pub efl: Dual<N>,
    pub epd: Dual<N>,
    /// Entrance pupil relative to the first vertex.
    pub entrance_pupil_z: Dual<N>,
    /// Exit pupil relative to the image plane.
    pub exit_pupil_z: Dual<N>,
    pub image_z: Dual<N>,
}

pub fn paraxial_tangents<const N: usize>(lens: &Lens, params: &[Param]) -> crate::Result<ParaxialTangents<N>> {
    use crate::lens::Aperture;
    let n = lens.indices(lens.primary_nm)?;
    let DualLens { surfs, image_z } = dual_lens::<N>(lens, params);
    let k = surfs.len();
    let thick: Vec<Dual<N>> = (0..k)
        .map(|i| {
            if i + 1 < k {
                surfs[i + 1].z - surfs[i].z
            } else {
                image_z - surfs[i].z
            }
        })
        .collect();
    let ynu = |y0: Dual<N>, u0: Dual<N>| {
        let (mut y, mut nu) = (y0, u0 * n[0]);
        let mut out = Vec::with_capacity(k);
        for (i, s) in surfs.iter().enumerate() {
            let a2 = s.a.first().copied().unwrap_or(Dual::constant(0.0));
            let c = s.c + a2 * 2.0;
            nu = nu - y * c * (n[i + 1] - n[i]);
            out.push((y, nu));
            y = y + thick[i] * nu * (1.0 / n[i + 1]);
        }
        out
    };
    let one = Dual::constant;
    let a = ynu(one(1.0), one(0.0));
    let b = ynu(one(0.0), one(1.0));
    let nua = a[k - 1].1;
    if nua.v.abs() < 1e-15 || lens.finite_object() {
        return Err(crate::error::EngineError::Argument(
            "paraxial tangents: an afocal lens or a finite object (not supported yet)".into(),
        ));
    }
    let efl = -(one(1.0) / nua);
    let entrance_pupil_z = b[lens.stop].0 / a[lens.stop].0;
    let epd = match lens.aperture {
        Aperture::Epd(d) => seeded(d, params, along(Param::Epd)),
        Aperture::FNumber(f) => (if efl.v < 0.0 { -efl } else { efl }) / seeded(f, params, along(Param::FNumber)),
        Aperture::ObjectNA(_) => unreachable!("a finite object was refused above"),
    };
    let (yc, nuc) = ynu(-entrance_pupil_z, one(1.0))[k - 1];
    let zx = surfs[k - 1].z - yc / (nuc * (1.0 / n[k]));
    Ok(ParaxialTangents {
        efl,
        epd,
        entrance_pupil_z,
        exit_pupil_z: zx - image_z,
        image_z,
    })
}

/// Paraxial aiming with tangents: the launch point of the ray through normalized pupil point
/// (x, y), i.e. through (x, y) EPD / 2 on the entrance-pupil plane, along `d` (an object at
/// infinity), on the beam's launch plane `z_launch` (`Beam::ray_from`'s arithmetic): where on
/// its line a ray starts changes its path and its plane-wave offset by the same amount, so
/// nothing downstream sees the plane move.
fn launch_along<const N: usize>(
    par: &ParaxialTangents<N>,
    z_launch: f64,
    x: f64,
    y: f64,
    d: &[Dual<N>; 3],
) -> [Dual<N>; 3] {
    let h = par.epd * 0.5;
    let back = (par.entrance_pupil_z - z_launch) / d[2];
    [
        h * x - back * d[0],
        h * y - back * d[1],
        par.entrance_pupil_z - back * d[2],
    ]
}

/// The beam's direction in dual numbers and its launch plane.
fn beam_frame<const N: usize>(beam: &crate::Beam) -> ([Dual<N>; 3], f64) {
    let d = beam.dir;
    (
        [Dual::constant(d.x), Dual::constant(d.y), Dual::constant(d.z)],
        beam.launch(0.0, 0.0).origin.z,
    )
}

/// What the fast FFT PSF takes from its coarse rays (psf/fast.rs), with tangents: for each
/// pupil point (px, py), the wavefront W (waves, against the reference sphere about the chief
/// ray's image point through the exit pupil) and the direction (L, M) from its point on the
/// sphere to the centre; the chief ray's image point and the sphere's radius. Paraxial
/// aiming, an object at infinity. None where a ray does not reach the image or the sphere.
#[derive(Clone, Debug)]
pub struct PupilTangents<const N: usize> {
    pub w: Vec<Dual<N>>,
    pub l: Vec<Dual<N>>,
    pub m: Vec<Dual<N>>,
    pub chief: [Dual<N>; 3],
    /// The chief ray's direction at the image.
    pub chief_dir: [Dual<N>; 3],
    pub radius: Dual<N>,
}

pub fn pupil_tangents<const N: usize>(
    sys: &System,
    params: &[Param],
    field_deg: f64,
    px: &[f64],
    py: &[f64],
) -> crate::Result<Option<PupilTangents<N>>> {
    let par = paraxial_tangents::<N>(sys.lens, params)?;
    let dl = dual_lens::<N>(sys.lens, params);
    let beam = crate::Beam::new(sys, field_deg, crate::Aiming::Paraxial)?;
    let (dir, z_launch) = beam_frame::<N>(&beam);
    let launch = |x: f64, y: f64| launch_along(&par, z_launch, x, y, &dir);
    let n0 = sys.n[0];
    let offset = |o: &[Dual<N>; 3]| dot(o, &dir) * n0;
    let c0 = launch(0.0, 0.0);
    let Some(chief) = trace_dual(sys, &dl, c0, dir) else {
        return Ok(None);
    };
    let n_img = sys.image_index();
    let tc = (par.image_z + par.exit_pupil_z - chief.p[2]) / chief.d[2];
    let radius = dot(&chief.d, &chief.d).sqrt() * (if tc.v < 0.0 { -tc } else { tc });
    let chief_sphere_opl = chief.opl + offset(&c0) - radius * n_img;
    let wl_mm = sys.wavelength_nm * 1e-6;
    let (mut w, mut l, mut m) = (vec![], vec![], vec![]);
    for (&x, &y) in px.iter().zip(py) {
        let o = launch(x, y);
        let Some(r) = trace_dual(sys, &dl, o, dir) else {
            return Ok(None);
        };
        // back along the ray to the sphere (pupil.rs back_to_sphere)
        let v = [r.p[0] - chief.p[0], r.p[1] - chief.p[1], r.p[2] - chief.p[2]];
        let vd = dot(&v, &r.d);
        let disc = vd * vd - dot(&v, &v) + radius * radius;
        if disc.v < 0.0 {
            return Ok(None);
        }
        let tt = -vd - disc.sqrt();
        w.push((r.opl + offset(&o) + tt * n_img - chief_sphere_opl) * (1.0 / wl_mm));
        l.push((chief.p[0] - (r.p[0] + tt * r.d[0])) / radius);
        m.push((chief.p[1] - (r.p[1] + tt * r.d[1])) / radius);
    }
    Ok(Some(PupilTangents {
        w,
        l,
        m,
        chief: chief.p,
        chief_dir: chief.d,
        radius,
    }))
}

/// The fast FFT PSF's polynomial fits with tangents (psf/fast.rs): over its coarse pupil set,
/// W and py as even, px as odd Legendre series in u = L / rho, v = (M - M_chief) / rho, rho the
/// rays' largest |L| or |M - M_chief|, at a given degree (the forward pass chooses it: a
/// discrete choice, fixed for the tangents). Coefficients in `fast::terms` order.
#[derive(Clone, Debug)]
pub struct FitTangents<const N: usize> {
    pub degree: usize,
    pub rho: Dual<N>,
    pub m_chief: Dual<N>,
    pub w: Vec<Dual<N>>,
    pub py: Vec<Dual<N>>,
    pub px: Vec<Dual<N>>,
}

/// Least squares of each of `ys` on the terms at the points (u, v), with tangents: the
/// coefficients c of min |Phi c - y| (fast.rs's `lsq`, by the normal equations and Cholesky)
/// and, by differentiating the normal equations Phi^T Phi c = Phi^T y,
///   Phi^T Phi dc = Phi^T (dy - dPhi c) + dPhi^T (y - Phi c),
/// dPhi = Phi_u du + Phi_v dv (the basis's slopes at the points as they move): one solve per
/// direction with the same factor. None where the system is singular.
fn lsq_tangents<const N: usize>(
    u: &[Dual<N>],
    v: &[Dual<N>],
    ys: &[&[Dual<N>]],
    tm: &[(usize, usize)],
    degree: usize,
) -> Option<Vec<Vec<Dual<N>>>> {
    use crate::psf::fast::{cholesky, cholesky_solve, legendre, MAX_DEGREE};
    let (m, t) = (u.len(), tm.len());
    let leg = |x: f64| {
        let (mut p, mut dp) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
        legendre(x, degree.min(MAX_DEGREE), &mut p, &mut dp);
        (p, dp)
    };
    // Phi, Phi_u, Phi_v (m x t, row-major)
    let (mut phi, mut phu, mut phv) = (vec![0.0; m * t], vec![0.0; m * t], vec![0.0; m * t]);
    for r in 0..m {
        let ((pu, dpu), (pv, dpv)) = (leg(u[r].v), leg(v[r].v));
        for (k, &(i, j)) in tm.iter().enumerate() {
            phi[r * t + k] = pu[i] * pv[j];
            phu[r * t + k] = dpu[i] * pv[j];
            phv[r * t + k] = pu[i] * dpv[j];
        }
    }
    let mut g = vec![0.0; t * t];
    for a in 0..t {
        for b in 0..=a {
            let x: f64 = (0..m).map(|r| phi[r * t + a] * phi[r * t + b]).sum();
            g[a * t + b] = x;
            g[b * t + a] = x;
        }
    }
    if !cholesky(&mut g, t) {
        return None;
    }
    let atb = |mat: &[f64], w: &[f64], out: &mut [f64]| {
        for (k, o) in out.iter_mut().enumerate() {
            *o += (0..m).map(|r| mat[r * t + k] * w[r]).sum::<f64>();
        }
    };
    Some(
        ys.iter()
            .map(|y| {
                let yv: Vec<f64> = y.iter().map(|x| x.v).collect();
                let mut c = vec![0.0; t];
                atb(&phi, &yv, &mut c);
                cholesky_solve(&g, t, &mut c);
                // the fitted function's slopes and residual at the points
                let row = |mat: &[f64], r: usize| (0..t).map(|k| mat[r * t + k] * c[k]).sum::<f64>();
                let fu: Vec<f64> = (0..m).map(|r| row(&phu, r)).collect();
                let fv: Vec<f64> = (0..m).map(|r| row(&phv, r)).collect();
                let res: Vec<f64> = (0..m).map(|r| yv[r] - row(&phi, r)).collect();
                let mut out: Vec<Dual<N>> = c.iter().map(|&x| Dual::constant(x)).collect();
                let (mut z, mut ru, mut rv) = (vec![0.0; m], vec![0.0; m], vec![0.0; m]);
                let mut b = vec![0.0; t];
                for n in 0..N {
                    for r in 0..m {
                        let (du, dv) = (u[r].d[n], v[r].d[n]);
                        z[r] = y[r].d[n] - fu[r] * du - fv[r] * dv;
                        ru[r] = res[r] * du;
                        rv[r] = res[r] * dv;
                    }
                    b.iter_mut().for_each(|x| *x = 0.0);
                    atb(&phi, &z, &mut b);
                    atb(&phu, &ru, &mut b);
                    atb(&phv, &rv, &mut b);
                    cholesky_solve(&g, t, &mut b);
                    for (o, x) in out.iter_mut().zip(&b) {
                        o.d[n] = *x;
                    }
                }
                out
            })
            .collect(),
    )
}

/// The fits of the fast FFT PSF at `field_deg` and `degree` with tangents along `params`.
pub fn fit_tangents<const N: usize>(
    sys: &System,
    params: &[Param],
    field_deg: f64,
    degree: usize,
) -> crate::Result<Option<FitTangents<N>>> {
    fits_along::<N>(sys, params, field_deg, degree, false)
}

/// [`fit_tangents`] with the scale rho held at its value where `fixed_scale` (its tangent
/// zero): the derivative of the fitted functions at fixed cells of the direction grid, which
/// is what the reverse pass of the fast PSF needs. (The fits span all polynomials of their
/// degree and parity, a space that scaling u, v leaves unchanged: the fitted functions of
/// (L, M - M_chief) do not depend on rho, only their coefficients do.)
pub(crate) fn fits_along<const N: usize>(
    sys: &System,
    params: &[Param],
    field_deg: f64,
    degree: usize,
    fixed_scale: bool,
) -> crate::Result<Option<FitTangents<N>>> {
    use crate::psf::fast::{terms, NT, N_RIM, R_RIM};
    use crate::psf::pupil::half_pupil;
    let (px, py) = half_pupil(NT, N_RIM, R_RIM);
    let Some(pt) = pupil_tangents::<N>(sys, params, field_deg, &px, &py)? else {
        return Ok(None);
    };
    let mc = pt.chief_dir[1];
    // rho: the largest |L| or |M - M_chief| (its ray's value, with its tangent)
    let mut rho = Dual::constant(0.0);
    for x in pt.l.iter().copied().chain(pt.m.iter().map(|m| *m - mc)) {
        let a = if x.v < 0.0 { -x } else { x };
        if a.v > rho.v {
            rho = a;
        }
    }
    if fixed_scale {
        rho = Dual::constant(rho.v);
    }
    let u: Vec<Dual<N>> = pt.l.iter().map(|l| *l / rho).collect();
    let v: Vec<Dual<N>> = pt.m.iter().map(|m| (*m - mc) / rho).collect();
    let k = Dual::<N>::constant;
    let (pxd, pyd): (Vec<Dual<N>>, Vec<Dual<N>>) =
        (px.iter().map(|x| k(*x)).collect(), py.iter().map(|y| k(*y)).collect());
    let (Some(even), Some(odd)) = (
        lsq_tangents(&u, &v, &[&pt.w, &pyd], &terms(degree, 0), degree),
        lsq_tangents(&u, &v, &[&pxd], &terms(degree, 1), degree),
    ) else {
        return Ok(None);
    };
    let mut even = even.into_iter();
    let (w, py) = (even.next().unwrap_or_default(), even.next().unwrap_or_default());
    Ok(Some(FitTangents {
        degree,
        rho,
        m_chief: mc,
        w,
        py,
        px: odd.into_iter().next().expect("one fit"),
    }))
}

/// The best-focus shift (focus.rs: the image-plane shift minimizing the mean over `fields`
/// of the polychromatic RMS spot squared on a polar grid of `rings`) with tangents; paraxial
/// aiming, an object at infinity. Rays the kernel does not bring to the image are left out,
/// as there.
pub fn best_focus_tangents<const N: usize>(
    lens: &Lens,
    params: &[Param],
    fields: &[f64],
    wavelengths: &[(f64, f64)],
    rings: usize,
) -> crate::Result<Dual<N>> {
    let par = paraxial_tangents::<N>(lens, params)?;
    let dl = dual_lens::<N>(lens, params);
    let wsum: f64 = wavelengths.iter().map(|p| p.1).sum();
    let (px, py) = crate::spot::polar_grid(rings);
    let systems = wavelengths
        .iter()
        .map(|p| System::new(lens, p.0))
        .collect::<crate::Result<Vec<_>>>()?;
    let zero = Dual::<N>::constant(0.0);
    let (mut b, mut c) = (zero, zero);
    let mut pts: Vec<[Dual<N>; 5]> = vec![];
    for &f in fields {
        pts.clear();
        for (sys, &(_, wt)) in systems.iter().zip(wavelengths) {
            let beam = crate::Beam::new(sys, f, crate::Aiming::Paraxial)?;
            let (dir, z_launch) = beam_frame::<N>(&beam);
            // flux weight: the launch's area (EPD / 2)^2 projected on the beam
            let h = par.epd * 0.5;
            let weight = h * h * (beam.dir.z * wt / wsum);
            for (&x, &y) in px.iter().zip(&py) {
                let Some(r) = trace_dual(sys, &dl, launch_along(&par, z_launch, x, y, &dir), dir) else {
                    continue;
                };
                if r.d[2].v.abs() > 1e-12 {
                    pts.push([r.p[0], r.p[1], r.d[0] / r.d[2], r.d[1] / r.d[2], weight]);
                }
            }
        }
        let sw = pts.iter().fold(zero, |a, p| a + p[4]);
        if !(sw.v > 0.0) {
            continue;
        }
        let mean = |k: usize| pts.iter().fold(zero, |a, p| a + p[4] * p[k]) / sw;
        let m = [mean(0), mean(1), mean(2), mean(3)];
        for p in &pts {
            let w = p[4] / sw;
            let (ax, ay, sx, sy) = (p[0] - m[0], p[1] - m[1], p[2] - m[2], p[3] - m[3]);
            b = b + w * (ax * sx + ay * sy);
            c = c + w * (sx * sx + sy * sy);
        }
    }
    Ok(if c.v > 0.0 { -(b / c) } else { zero })
}

/// The image irradiance of `spot::irradiance` with tangents (a flat image, paraxial aiming, an
/// object at infinity): the flux of each pupil point over |det J| of its image-plane Jacobian
/// in the launch direction (central differences of unclipped rays, as there), after the one
/// Newton step onto the chief ray's image point; the pupil grid the forward pass chose (the
/// Gauss grid where the beam is clear, else the fine polar one: a discrete choice, fixed).
pub fn irradiance_tangents<const N: usize>(
    lens: &Lens,
    params: &[Param],
    field_deg: f64,
    wavelength_nm: f64,
) -> crate::Result<Dual<N>> {
    use crate::spot::{irradiance, PupilGrid, RI_RINGS, RI_STEP};
    if lens.image_curvature != 0.0 {
        return Err(crate::error::EngineError::Argument(
            "irradiance tangents: a curved image (not supported yet)".into(),
        ));
    }
    let clear = irradiance(
        lens,
        field_deg,
        wavelength_nm,
        PupilGrid::Clear,
        crate::Aiming::Paraxial,
    )?
    .1;
    let (px, py, pw) = if clear {
        PupilGrid::Clear
    } else {
        PupilGrid::Rings(RI_RINGS)
    }
    .points();
    let par = paraxial_tangents::<N>(lens, params)?;
    let dl = dual_lens::<N>(lens, params);
    let sys = System::new(lens, wavelength_nm)?;
    let mut open = System::new(lens, wavelength_nm)?;
    open.clip = false;
    let beam = crate::Beam::new(&sys, field_deg, crate::Aiming::Paraxial)?;
    let (beam_dir, z_launch) = beam_frame::<N>(&beam);
    let d0 = beam.dir;
    let k = Dual::<N>::constant;
    // a direction about the beam's (the launch: on the entrance-pupil point's line along it)
    let dir = |a: Dual<N>, b: Dual<N>| {
        let (x, y) = (a + d0.x, b + d0.y);
        [x, y, (-(x * x) - y * y + 1.0).sqrt()]
    };
    let h = par.epd * 0.5;
    let chief = trace_dual(&open, &dl, launch_along(&par, z_launch, 0.0, 0.0, &beam_dir), beam_dir);
    let mut e = k(0.0);
    for ((&x, &y), &w) in px.iter().zip(&py).zip(&pw) {
        let steps = [
            (0.0, 0.0),
            (RI_STEP, 0.0),
            (-RI_STEP, 0.0),
            (0.0, RI_STEP),
            (0.0, -RI_STEP),
        ];
        let g: Option<Vec<RayTangents<N>>> = steps
            .iter()
            .map(|&(a, b)| {
                let d = dir(k(a), k(b));
                trace_dual(&open, &dl, launch_along(&par, z_launch, x, y, &d), d)
            })
            .collect();
        let Some(g) = g else { continue };
        let s2 = 2.0 * RI_STEP;
        let j = [
            [
                (g[1].p[0] - g[2].p[0]) * (1.0 / s2),
                (g[3].p[0] - g[4].p[0]) * (1.0 / s2),
            ],
            [
                (g[1].p[1] - g[2].p[1]) * (1.0 / s2),
                (g[3].p[1] - g[4].p[1]) * (1.0 / s2),
            ],
        ];
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.v.abs() > 1e-300) {
            continue;
        }
        let (step_l, step_m) = match &chief {
            Some(c) => {
                let (rx, ry) = (c.p[0] - g[0].p[0], c.p[1] - g[0].p[1]);
                (
                    (j[1][1] * rx - j[0][1] * ry) / det,
                    (-(j[1][0] * rx) + j[0][0] * ry) / det,
                )
            }
            None => (k(0.0), k(0.0)),
        };
        // whether the clipped system passes the ray (the kernel's f64 trace: no tangents needed)
        let d = dir(step_l, step_m);
        let o = launch_along(&par, z_launch, x, y, &d);
        let real = |x: &[Dual<N>; 3]| DVec3::new(x[0].v, x[1].v, x[2].v);
        if sys.trace(real(&o), real(&d), End::Image).ok() {
            let adet = if det.v < 0.0 { -det } else { det };
            e = e + h * h * w / adet;
        }
    }
    Ok(e)
}

/// `spot::relative_illumination_from` with tangents: the irradiance at the field over the
/// same on the axis (1 at the axis itself).
pub fn relative_illumination_tangents<const N: usize>(
    lens: &Lens,
    params: &[Param],
    field_deg: f64,
    wavelength_nm: f64,
) -> crate::Result<Dual<N>> {
    if field_deg == 0.0 {
        return Ok(Dual::constant(1.0));
    }
    Ok(irradiance_tangents(lens, params, field_deg, wavelength_nm)?
        / irradiance_tangents(lens, params, 0.0, wavelength_nm)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::psf::fast::{legendre_table, lsq, terms, NT, N_RIM, R_RIM};
    use crate::psf::pupil::half_pupil;

    /// A sampled design of the detect-wide space (tests/data/lenses), aspheric surfaces 1 and 6.
    fn detect_wide() -> Lens {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/data/lenses/detect_wide_f3.2.json"
        );
        Lens::from_json(&std::fs::read_to_string(path).unwrap()).unwrap()
    }

    /// The fits by fast.rs's own f64 code from the coarse data's values (pupil_tangents's
    /// values are the kernel's: tests/engine/tangent.rs).
    fn fits(lens: &Lens, wl: f64, field: f64, deg: usize) -> Vec<f64> {
        let sys = System::new(lens, wl).unwrap();
        let (px, py) = half_pupil(NT, N_RIM, R_RIM);
        let pt = pupil_tangents::<1>(&sys, &[], field, &px, &py).unwrap().unwrap();
        let mc = pt.chief_dir[1].v;
        let (l, m): (Vec<f64>, Vec<f64>) = (pt.l.iter().map(|x| x.v).collect(), pt.m.iter().map(|x| x.v).collect());
        let rho = l
            .iter()
            .map(|x| x.abs())
            .chain(m.iter().map(|y| (y - mc).abs()))
            .fold(0.0, f64::max);
        let u: Vec<f64> = l.iter().map(|x| x / rho).collect();
        let v: Vec<f64> = m.iter().map(|y| (y - mc) / rho).collect();
        let w: Vec<f64> = pt.w.iter().map(|x| x.v).collect();
        let (pu, pv) = (legendre_table(&u), legendre_table(&v));
        let (ce, _) = lsq(&pu, &pv, &[&w, &py], &terms(deg, 0)).unwrap();
        let (co, _) = lsq(&pu, &pv, &[&px], &terms(deg, 1)).unwrap();
        let mut out = vec![rho, mc];
        out.extend(ce.concat());
        out.extend(co.concat());
        out
    }

    #[test]
    fn the_fits_coefficients_have_the_tangents_of_their_differences() {
        let lens = detect_wide();
        let params = [
            Param::Curvature(0),
            Param::Aspheric(0, 1),
            Param::Thickness(1),
            Param::Conic(5),
            Param::Thickness(4),
        ];
        // steps where each difference is clear of its round-off (a conic moves W by 0.009
        // waves per unit: 1e-3)
        let steps = [1e-6, 1e-8, 1e-5, 1e-3, 1e-5];
        let (wl, deg) = (550.0, 8);
        let sys = System::new(&lens, wl).unwrap();
        for field in [0.0, lens.max_field_deg()] {
            let f = fit_tangents::<5>(&sys, &params, field, deg).unwrap().unwrap();
            let mut tan: Vec<[f64; 5]> = vec![f.rho.d, f.m_chief.d];
            tan.extend(f.w.iter().chain(&f.py).chain(&f.px).map(|x| x.d));
            let base = fits(&lens, wl, field, deg);
            assert_eq!(base.len(), tan.len());
            assert!((f.w[0].v - base[2]).abs() < 1e-9 * base[2].abs().max(1.0));
            for (k, (&p, &h)) in params.iter().zip(&steps).enumerate() {
                let (a, b) = (
                    fits(&perturbed(&lens, p, h).unwrap(), wl, field, deg),
                    fits(&perturbed(&lens, p, -h).unwrap(), wl, field, deg),
                );
                let fd: Vec<f64> = a.iter().zip(&b).map(|(a, b)| (a - b) / (2.0 * h)).collect();
                // W's coefficients (waves) against W's largest, the maps' against theirs
                let nw = f.w.len();
                for range in [0..2, 2..2 + nw, 2 + nw..fd.len()] {
                    let scale = fd[range.clone()].iter().fold(0.0f64, |m, x| m.max(x.abs()));
                    for i in range {
                        let err = (fd[i] - tan[i][k]).abs();
                        assert!(
                            err <= 1e-4 * scale + 1e-6,
                            "{p:?} at {field} deg [{i}]: {} against {}",
                            tan[i][k],
                            fd[i]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_best_focus_shift_has_the_tangent_of_its_difference() {
        use crate::focus::best_focus_shift;
        let lens = detect_wide();
        let params = [
            Param::Curvature(0),
            Param::Aspheric(0, 0),
            Param::Thickness(1),
            Param::Conic(5),
            Param::Thickness(6),
            Param::FNumber,
        ];
        let steps = [1e-6, 1e-7, 1e-5, 1e-4, 1e-5, 1e-4];
        let (fields, wls) = ([0.0, 7.0, 10.0, 14.9], [(470.0, 1.0), (550.0, 2.0), (650.0, 1.0)]);
        let t = best_focus_tangents::<6>(&lens, &params, &fields, &wls, 4).unwrap();
        let at = |l: &Lens| best_focus_shift(l, &fields, &wls, 4, crate::Aiming::Paraxial).unwrap();
        assert!((t.v - at(&lens)).abs() < 1e-12, "{} against {}", t.v, at(&lens));
        let mut moved = 0;
        for (k, (&p, &h)) in params.iter().zip(&steps).enumerate() {
            let fd = (at(&perturbed(&lens, p, h).unwrap()) - at(&perturbed(&lens, p, -h).unwrap())) / (2.0 * h);
            assert!(
                (fd - t.d[k]).abs() <= 1e-5 * fd.abs() + 1e-7,
                "{p:?}: {} against {fd}",
                t.d[k]
            );
            moved += (fd.abs() > 1e-4) as usize;
        }
        // the back focus moves the plane one for one (the shift is from the plane)
        assert!((t.d[4] + 1.0).abs() < 1e-9 && moved == params.len(), "{:?}", t.d);
        assert!(perturbed(&lens, Param::Epd, 0.1).is_none()); // an f-number lens has no EPD to move
    }

    #[test]
    fn the_relative_illumination_has_the_tangent_of_its_difference() {
        use crate::spot::relative_illumination_from;
        let lens = detect_wide();
        let params = [
            Param::Curvature(0),
            Param::Aspheric(0, 1),
            Param::Thickness(1),
            Param::Thickness(4),
            Param::Thickness(6),
            Param::FNumber,
        ];
        let steps = [1e-6, 1e-8, 1e-5, 1e-5, 1e-5, 1e-4];
        let at = |l: &Lens, f: f64| relative_illumination_from(l, f, 550.0, crate::Aiming::Paraxial, None).unwrap();
        for field in [9.0, 14.9] {
            let t = relative_illumination_tangents::<6>(&lens, &params, field, 550.0).unwrap();
            assert!(
                (t.v - at(&lens, field)).abs() < 1e-9,
                "{} against {}",
                t.v,
                at(&lens, field)
            );
            for (k, (&p, &h)) in params.iter().zip(&steps).enumerate() {
                let fd = (at(&perturbed(&lens, p, h).unwrap(), field) - at(&perturbed(&lens, p, -h).unwrap(), field))
                    / (2.0 * h);
                assert!(
                    (fd - t.d[k]).abs() <= 1e-4 * fd.abs() + 1e-5,
                    "{p:?} at {field} deg: {} against {fd}",
                    t.d[k]
                );
            }
            assert!(t.d.iter().filter(|x| x.abs() > 1e-3).count() >= 3, "{:?}", t.d);
        }
    }
}
