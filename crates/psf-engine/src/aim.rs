//! Launching the beam of a field angle (field along +y): collimated for an object at
//! infinity; from one object point for a finite object, placed as OpticStudio places an
//! angle field there (its chief ray leaves at the field angle towards the centre of the
//! paraxial entrance pupil: object height -L tan(field), L = object to entrance pupil).
//!
//! Paraxial aiming sends ray (px, py) through the point (px, py) * EPD/2 of the paraxial
//! entrance pupil (what most tools, and the reference data, do). Real aiming moves the
//! ray's entry point until it crosses the real stop at (px, py) times the stop radius, by
//! Newton iteration on a finite-difference Jacobian. The stop radius is where the on-axis
//! real marginal ray of the specified EPD crosses the stop, so the axial beam keeps the
//! specified diameter and off-axis beams fill the same physical stop.

use crate::error::{arg, EngineError, Result};
use crate::kernel::Block;
use crate::paraxial::{paraxial, Paraxial};
use crate::trace::{End, RayState, Status, System, Traced};
use glam::{DVec2, DVec3};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Aiming {
    Paraxial,
    Real,
}

impl std::str::FromStr for Aiming {
    type Err = EngineError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "paraxial" => Ok(Aiming::Paraxial),
            "real" => Ok(Aiming::Real),
            _ => arg(format!("aiming must be \"paraxial\" or \"real\", got \"{s}\"")),
        }
    }
}

/// One launched ray: origin, direction and the entrance-plane area it stands for per unit
/// pupil-coordinate area (d(ex, ey)/d(px, py)).
#[derive(Clone, Copy, Debug)]
pub struct Launch {
    pub origin: DVec3,
    pub dir: DVec3,
    pub area: f64,
    pub ok: bool,
}

pub struct Beam<'s, 'l> {
    pub sys: &'s System<'l>,
    /// First-order data at the lens's primary wavelength (pupils do not follow colour).
    pub par: Paraxial,
    pub field_deg: f64,
    /// Direction of the ray through the entrance pupil's centre (every ray's, for an object
    /// at infinity).
    pub dir: DVec3,
    /// The object point of a finite object; None at infinity.
    pub object: Option<DVec3>,
    pub aiming: Aiming,
    z_launch: f64,
    /// Real aiming: entry point of the chief ray and d(stop)/d(entry) there.
    chief_entry: DVec2,
    chief_jac: [[f64; 2]; 2],
    /// Real aiming: the stop radius that the specified EPD fills on axis.
    pub stop_radius: f64,
}

const AIM_TOL: f64 = 1e-10;
const FD_STEP: f64 = 1e-6;

impl<'s, 'l> Beam<'s, 'l> {
    pub fn new(sys: &'s System<'l>, field_deg: f64, aiming: Aiming) -> Result<Self> {
        if !(field_deg.is_finite() && field_deg.abs() < 90.0) {
            return arg(format!("field angle {field_deg} deg must be within (-90, 90)"));
        }
        let lens = sys.lens;
        let par = paraxial(lens, lens.primary_nm)?;
        let t = field_deg.to_radians();
        let dir = DVec3::new(0.0, t.sin(), t.cos());
        // Launch plane well before the first surface and the entrance pupil.
        let s1 = &lens.surfaces[0];
        let reach = s1.semi_diameter.unwrap_or(par.epd);
        let dip = crate::surface::sag(s1, reach * reach)
            .map(|z| (-z).max(0.0))
            .unwrap_or(reach);
        let object = lens
            .finite_object()
            .then(|| DVec3::new(0.0, -par.object_to_pupil * t.tan(), -lens.object_distance));
        let z_obj = if lens.finite_object() {
            -lens.object_distance
        } else {
            0.0
        };
        // (for a finite object any point of a ray's line serves: before or after the object)
        let z_launch = par.entrance_pupil_z.min(0.0) - 10.0 - dip;
        let mut b = Beam {
            sys,
            par,
            field_deg,
            dir,
            object,
            aiming,
            z_launch,
            chief_entry: DVec2::ZERO,
            chief_jac: [[1.0, 0.0], [0.0, 1.0]],
            stop_radius: par.stop_semi_diameter,
        };
        if aiming == Aiming::Real {
            // The stop's real size: the height at which the on-axis marginal ray of the
            // specified EPD crosses it, so the on-axis entrance pupil keeps its diameter.
            let h = 0.5 * par.epd;
            let axial = object.map(|_| DVec3::new(0.0, 0.0, z_obj));
            let (o, d) = b.ray_from(axial, DVec3::Z, DVec2::new(0.0, h));
            let r = sys.trace_unclipped(o, d, End::Surface(lens.stop));
            if !r.ok() {
                return Err(EngineError::Trace(format!(
                    "real ray aiming: the on-axis marginal ray does not reach the stop ({:?} at surface {})",
                    r.status,
                    r.surface + 1
                )));
            }
            b.stop_radius = r.p.y.abs();
            let (e, j) = b.aim_at(DVec2::ZERO, DVec2::ZERO, None).ok_or_else(|| {
                EngineError::Trace(format!(
                    "real ray aiming: the chief ray at {field_deg} deg cannot be aimed at the stop centre"
                ))
            })?;
            b.chief_entry = e;
            b.chief_jac = j;
        }
        Ok(b)
    }

    /// Origin (on the launch plane) and direction of the ray entering through point `e` of
    /// the entrance-pupil plane: along `dir` from infinity, or on the line from the object
    /// point (travelling towards +z).
    #[inline]
    fn ray_from(&self, object: Option<DVec3>, dir: DVec3, e: DVec2) -> (DVec3, DVec3) {
        let ze = self.par.entrance_pupil_z;
        let q = DVec3::new(e.x, e.y, ze);
        let d = match object {
            None => dir,
            Some(o) => ((q - o) * (q.z - o.z).signum()).normalize(),
        };
        (q - ((ze - self.z_launch) / d.z) * d, d)
    }

    #[inline]
    fn ray(&self, e: DVec2) -> (DVec3, DVec3) {
        self.ray_from(self.object, self.dir, e)
    }

    fn stop_hit(&self, e: DVec2) -> Option<DVec2> {
        let (o, d) = self.ray(e);
        let r = self.sys.trace_unclipped(o, d, End::Surface(self.sys.lens.stop));
        r.ok().then(|| DVec2::new(r.p.x, r.p.y))
    }

    /// Newton iteration for the entry point whose ray crosses the stop at `target`.
    fn aim_at(&self, target: DVec2, guess: DVec2, jac0: Option<[[f64; 2]; 2]>) -> Option<(DVec2, [[f64; 2]; 2])> {
        let mut e = guess;
        let mut s = self.stop_hit(e)?;
        let mut jac = jac0.unwrap_or([[1.0, 0.0], [0.0, 1.0]]);
        let mut fresh = false;
        for it in 0..40 {
            let r = s - target;
            if r.length() < AIM_TOL && fresh {
                return Some((e, jac));
            }
            if it == 0 || !fresh || r.length() > 1e-3 {
                let sx = self.stop_hit(e + DVec2::new(FD_STEP, 0.0))?;
                let sy = self.stop_hit(e + DVec2::new(0.0, FD_STEP))?;
                jac = [
                    [(sx.x - s.x) / FD_STEP, (sy.x - s.x) / FD_STEP],
                    [(sx.y - s.y) / FD_STEP, (sy.y - s.y) / FD_STEP],
                ];
                fresh = true;
            }
            let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
            if det.abs() < 1e-14 {
                return None;
            }
            let step = DVec2::new(
                (jac[1][1] * r.x - jac[0][1] * r.y) / det,
                (-jac[1][0] * r.x + jac[0][0] * r.y) / det,
            );
            // Damped step: halve until the ray still reaches the stop.
            let mut lam = 1.0;
            loop {
                let cand = e - lam * step;
                if let Some(sc) = self.stop_hit(cand) {
                    e = cand;
                    s = sc;
                    break;
                }
                lam *= 0.5;
                if lam < 1e-6 {
                    return None;
                }
            }
            if r.length() < AIM_TOL {
                return Some((e, jac));
            }
        }
        None
    }

    /// Launch ray (px, py) in normalized pupil coordinates.
    pub fn launch(&self, px: f64, py: f64) -> Launch {
        match self.aiming {
            Aiming::Paraxial => {
                let h = 0.5 * self.par.epd;
                let (origin, dir) = self.ray(DVec2::new(px * h, py * h));
                Launch {
                    origin,
                    dir,
                    area: h * h,
                    ok: true,
                }
            }
            Aiming::Real => {
                let rs = self.stop_radius;
                let target = DVec2::new(px * rs, py * rs);
                // Linear predictor from the chief ray's Jacobian.
                let j = self.chief_jac;
                let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
                let guess = self.chief_entry
                    + DVec2::new(
                        (j[1][1] * target.x - j[0][1] * target.y) / det,
                        (-j[1][0] * target.x + j[0][0] * target.y) / det,
                    );
                match self.aim_at(target, guess, Some(j)) {
                    Some((e, jac)) => {
                        let d = (jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0]).abs();
                        let (origin, dir) = self.ray(e);
                        Launch {
                            origin,
                            dir,
                            area: rs * rs / d,
                            ok: true,
                        }
                    }
                    None => {
                        let (origin, dir) = self.ray(guess);
                        Launch {
                            origin,
                            dir,
                            area: 0.0,
                            ok: false,
                        }
                    }
                }
            }
        }
    }

    /// Origin of the ray that crosses the entrance-pupil plane where launch `l` does, but
    /// travels along `d` (unit, d.z > 0): the same pupil point seen from a neighbouring
    /// object direction (a neighbouring object point, for a finite object).
    pub fn origin_along(&self, l: &Launch, d: DVec3) -> DVec3 {
        let ze = self.par.entrance_pupil_z;
        let q = l.origin + ((ze - l.origin.z) / l.dir.z) * l.dir;
        q - ((ze - self.z_launch) / d.z) * d
    }

    /// Optical path from the incident wavefront to the launch point, added to a traced OPL
    /// to put every ray on a common wavefront: for an object at infinity the plane through
    /// the global origin; for a finite object the object point itself (a launch point before
    /// it on its ray is a negative path back to it, one after it a positive path).
    #[inline]
    pub fn wavefront_offset(&self, origin: DVec3) -> f64 {
        match self.object {
            None => self.sys.n[0] * origin.dot(self.dir),
            Some(o) => self.sys.n[0] * (origin - o).length() * (origin.z - o.z).signum(),
        }
    }

    /// Irradiance weight of a launched ray per unit pupil-coordinate area: its
    /// entrance-plane area projected on the beam (cos of the field angle) from infinity;
    /// from a Lambertian object point, cos(t) of the emission times the solid angle
    /// dA cos(t) / r^2 of its pupil area, r = L / cos(t): area cos^4(t) / L^2 per unit
    /// object area, taken per unit of the solid angle cos^3(field) / L^2 that the object
    /// area subtends (so a far object tends to the object at infinity).
    #[inline]
    pub fn flux_weight(&self, l: &Launch) -> f64 {
        match self.object {
            None => l.area * self.dir.z,
            Some(_) => l.area * l.dir.z.powi(4) / self.dir.z.powi(3),
        }
    }

    /// `flux_weight` of a paraxially aimed ray from its launch point (paraxial launches all
    /// carry the area (EPD/2)^2).
    #[inline]
    pub fn paraxial_flux_weight(&self, origin: DVec3) -> f64 {
        let h = 0.5 * self.par.epd;
        match self.object {
            None => h * h * self.dir.z,
            Some(o) => h * h * (o - origin).normalize().z.abs().powi(4) / self.dir.z.powi(3),
        }
    }

    /// Launch rays at pupil points (in parallel; paraxial launches are closed-form).
    pub fn launches(&self, px: &[f64], py: &[f64]) -> Vec<Launch> {
        use rayon::prelude::*;
        px.par_iter()
            .zip(py.par_iter())
            .with_min_len(256)
            .map(|(&x, &y)| self.launch(x, y))
            .collect()
    }

    /// Fill a kernel block with launched rays `start..start + b.len`; unaimable rays are
    /// marked Missed at surface 0.
    fn load(&self, launches: &[Launch], start: usize, b: &mut Block) {
        for j in 0..b.len {
            let l = &launches[start + j];
            b.set(j, l.origin.to_array(), l.dir.to_array());
            if !l.ok {
                b.status[j] = Status::Missed as u8;
                b.surface[j] = 0;
            }
        }
    }

    /// Launch and trace rays at pupil points; unaimable rays come back Missed at surface 0.
    pub fn trace_pupil(&self, px: &[f64], py: &[f64]) -> (Vec<Launch>, Vec<RayState>) {
        let launches = self.launches(px, py);
        let rays = self
            .sys
            .trace_launched(launches.len(), |start, b| self.load(&launches, start, b));
        (launches, rays)
    }

    /// Launch and trace rays at pupil points into flat arrays (see `System::trace_soa`).
    pub fn trace_pupil_soa(&self, px: &[f64], py: &[f64]) -> Traced {
        self.trace_pupil_to(px, py, End::Image)
    }

    /// Launch rays at pupil points and trace them to `end`: the image plane, or the
    /// intersection with a surface (before refracting there).
    pub fn trace_pupil_to(&self, px: &[f64], py: &[f64], end: End) -> Traced {
        let launches = (self.aiming == Aiming::Real).then(|| self.launches(px, py));
        self.trace_with(self.sys, launches.as_deref(), px, py, end)
    }

    /// Trace through `sys` (this beam's system or an unclipped copy) with the launches
    /// computed once (`None`: paraxial launches, computed in the loader).
    fn trace_with(&self, sys: &System, launches: Option<&[Launch]>, px: &[f64], py: &[f64], end: End) -> Traced {
        match launches {
            // Paraxial launches are computed in the kernel's loader: no intermediate array.
            None if self.object.is_some() => {
                let h = 0.5 * self.par.epd;
                sys.trace_soa(px.len(), end, |start, b| {
                    for j in 0..b.len {
                        let (o, d) = self.ray(DVec2::new(px[start + j] * h, py[start + j] * h));
                        b.set(j, o.to_array(), d.to_array());
                    }
                })
            }
            None => {
                let h = 0.5 * self.par.epd;
                let d = self.dir.to_array();
                // ray(e).0 = ray(0).0 + (e, 0), bit for bit.
                let o0 = self.ray(DVec2::ZERO).0;
                sys.trace_soa(px.len(), end, |start, b| {
                    for j in 0..b.len {
                        b.set(j, [px[start + j] * h + o0.x, py[start + j] * h + o0.y, o0.z], d);
                    }
                })
            }
            Some(l) => sys.trace_soa(px.len(), end, |start, b| self.load(l, start, b)),
        }
    }

    /// Each ray's path through every surface and onto the image plane (for layouts).
    ///
    /// Point `i` of a ray is its intersection with surface `i` (`i` = surfaces.len(): the
    /// image plane), from the same kernel as the image trace, so the last point of a ray
    /// that reaches the image equals `trace_pupil_soa` bit for bit. A failed ray stops
    /// where it failed: a clipped ray keeps its hit point on the surface that clipped it
    /// (outside the clear aperture), a TIR ray the point where it reflected, a ray that
    /// missed a surface the point before. Points after `last` are zero.
    pub fn trace_path(&self, px: &[f64], py: &[f64]) -> Result<RayPath> {
        if px.len() != py.len() {
            return arg(format!("px ({}) and py ({}) differ in length", px.len(), py.len()));
        }
        let (n, k) = (px.len(), self.sys.lens.surfaces.len());
        let launches = (self.aiming == Aiming::Real).then(|| self.launches(px, py));
        let launches = launches.as_deref();
        let image = self.trace_with(self.sys, launches, px, py, End::Image);
        // Geometry does not depend on clipping: an unclipped copy gives the hit point of
        // a ray on the surface whose clear aperture stopped it.
        let mut open = System::new(self.sys.lens, self.sys.wavelength_nm)?;
        open.clip = false;
        let clipped_at = |j: usize| (image.status[j] == Status::Clipped as u8).then_some(image.surface[j]);
        let mut position = vec![0.0; n * (k + 1) * 3];
        let mut last = vec![-1i32; n];
        for i in 0..=k {
            let end = if i == k { End::Image } else { End::Surface(i) };
            let here = if i == k {
                None
            } else {
                Some(self.trace_with(self.sys, launches, px, py, end))
            };
            let t = here.as_ref().unwrap_or(&image);
            let unclipped = (0..n)
                .any(|j| clipped_at(j) == Some(i as i32))
                .then(|| self.trace_with(&open, launches, px, py, end));
            for j in 0..n {
                let src = if t.status[j] == Status::Ok as u8 {
                    &t.position
                } else if clipped_at(j) == Some(i as i32) {
                    &unclipped.as_ref().unwrap().position
                } else {
                    continue;
                };
                let o = (j * (k + 1) + i) * 3;
                position[o..o + 3].copy_from_slice(&src[3 * j..3 * j + 3]);
                last[j] = i as i32;
            }
        }
        Ok(RayPath {
            points: k + 1,
            position,
            last,
            image,
        })
    }
}

/// Largest radial height at each of the first `n_surfaces` surfaces of the pupil rays
/// (px, py) of every field and wavelength that reach the image (0 where none does): Zemax's
/// automatic semi-diameters, in one call (`Beam::trace_path` per field and wavelength). The
/// first error, fields outer, is returned as it is.
pub fn ray_footprint(
    lens: &crate::Lens,
    n_surfaces: usize,
    fields_deg: &[f64],
    wavelengths_nm: &[f64],
    px: &[f64],
    py: &[f64],
    aiming: Aiming,
) -> Result<Vec<f64>> {
    let mut h = vec![0.0f64; n_surfaces];
    let systems: Vec<Result<System>> = wavelengths_nm.iter().map(|&wl| System::new(lens, wl)).collect();
    for &f in fields_deg {
        for sys in &systems {
            let sys = sys.as_ref().map_err(|e| e.clone())?;
            let p = Beam::new(sys, f, aiming)?.trace_path(px, py)?;
            if p.points < n_surfaces {
                return arg(format!(
                    "ray_footprint: {n_surfaces} surfaces asked, the lens has {}",
                    p.points - 1
                ));
            }
            for (j, &st) in p.image.status.iter().enumerate() {
                if st != Status::Ok as u8 {
                    continue;
                }
                for (s, hs) in h.iter_mut().enumerate() {
                    let o = (j * p.points + s) * 3;
                    *hs = hs.max(p.position[o].hypot(p.position[o + 1]));
                }
            }
        }
    }
    Ok(h)
}

/// Ray paths through a lens (`Beam::trace_path`).
#[derive(Clone, Debug, Default)]
pub struct RayPath {
    /// Points per ray: one per surface plus the image plane.
    pub points: usize,
    /// Row-major (n, points, 3), global frame; zeros after `last`.
    pub position: Vec<f64>,
    /// Index of each ray's last valid point, or -1 (none: missed surface 1 or not aimable).
    pub last: Vec<i32>,
    /// The trace to the image plane: launch points, status, failing surface, and the
    /// direction and optical path at the image of the rays that arrived.
    pub image: Traced,
}
