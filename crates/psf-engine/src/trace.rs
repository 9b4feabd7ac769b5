//! Real ray tracing of ray batches. Every ray ends with a status code instead of NaN:
//! it reached the image plane, missed a surface, was clipped by a clear aperture, or was
//! totally internally reflected; failed rays keep the index of the surface at fault.

use crate::error::Result;
use crate::lens::Lens;
use crate::surface::{intersect, refract};
use glam::DVec3;
use rayon::prelude::*;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Status {
    Ok = 0,
    Missed = 1,
    Clipped = 2,
    Tir = 3,
    Invalid = 4,
}

#[derive(Clone, Copy, Debug)]
pub struct RayState {
    /// Position (global frame) at the last surface reached.
    pub p: DVec3,
    /// Unit direction after that surface.
    pub d: DVec3,
    /// Optical path length from the launch point.
    pub opl: f64,
    pub status: Status,
    /// Surface index (0-based, len = image plane) where the ray failed, or -1.
    pub surface: i32,
}

impl RayState {
    pub fn ok(&self) -> bool {
        self.status == Status::Ok
    }
    fn fail(status: Status, surface: usize) -> RayState {
        RayState { p: DVec3::ZERO, d: DVec3::ZERO, opl: 0.0, status, surface: surface as i32 }
    }
}

/// A lens evaluated at one wavelength, ready to trace.
pub struct System<'a> {
    pub lens: &'a Lens,
    pub wavelength_nm: f64,
    /// Index of each medium (0: object space).
    pub n: Vec<f64>,
    /// Respect clear semi-diameters (vignetting); off for aiming probes.
    pub clip: bool,
}

/// Where a trace stops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum End {
    Image,
    /// Stop at the intersection with this surface (0-based), before refracting there.
    Surface(usize),
}

/// Rays per rayon task: large enough to amortize scheduling, small enough to balance.
const CHUNK: usize = 2048;

impl<'a> System<'a> {
    pub fn new(lens: &'a Lens, wavelength_nm: f64) -> Result<Self> {
        Ok(System { lens, wavelength_nm, n: lens.indices(wavelength_nm)?, clip: true })
    }

    pub fn image_index(&self) -> f64 {
        *self.n.last().unwrap()
    }

    /// Trace one ray from `p` (global) along unit `d` in object space.
    #[inline]
    pub fn trace(&self, p: DVec3, d: DVec3, end: End) -> RayState {
        self.trace_opts(p, d, end, self.clip)
    }

    #[inline]
    fn trace_opts(&self, mut p: DVec3, mut d: DVec3, end: End, clip: bool) -> RayState {
        if !(p.is_finite() && d.is_finite()) || (d.length_squared() - 1.0).abs() > 1e-9 {
            return RayState::fail(Status::Invalid, 0);
        }
        let mut opl = 0.0;
        let last = match end {
            End::Image => self.lens.surfaces.len(),
            End::Surface(i) => i + 1,
        };
        for (i, s) in self.lens.surfaces[..last].iter().enumerate() {
            let local = DVec3::new(p.x, p.y, p.z - s.z);
            let Some((t, nrm)) = intersect(s, local, d) else {
                return RayState::fail(Status::Missed, i);
            };
            p += t * d;
            opl += self.n[i] * t;
            if clip {
                if let Some(sd) = s.semi_diameter {
                    if p.x * p.x + p.y * p.y > sd * sd {
                        return RayState::fail(Status::Clipped, i);
                    }
                }
            }
            if end == End::Surface(i) {
                return RayState { p, d, opl, status: Status::Ok, surface: -1 };
            }
            match refract(d, nrm, self.n[i], self.n[i + 1]) {
                Some(dn) => d = dn,
                None => return RayState::fail(Status::Tir, i),
            }
        }
        let k = self.lens.surfaces.len();
        if d.z <= 0.0 {
            return RayState::fail(Status::Missed, k);
        }
        let t = (self.lens.image_z - p.z) / d.z;
        p += t * d;
        opl += self.n[k] * t;
        if clip {
            if let Some(sd) = self.lens.image_semi_diameter {
                if p.x * p.x + p.y * p.y > sd * sd {
                    return RayState::fail(Status::Clipped, k);
                }
            }
        }
        RayState { p, d, opl, status: Status::Ok, surface: -1 }
    }

    /// Trace a batch in parallel; output order matches input order.
    pub fn trace_many(&self, origins: &[DVec3], dirs: &[DVec3]) -> Vec<RayState> {
        let mut out = vec![RayState::fail(Status::Invalid, 0); origins.len()];
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(ci, chunk)| {
            let base = ci * CHUNK;
            for (j, o) in chunk.iter_mut().enumerate() {
                *o = self.trace(origins[base + j], dirs[base + j], End::Image);
            }
        });
        out
    }
}

impl<'a> System<'a> {
    /// Trace ignoring clear apertures (used for aiming probes).
    pub fn trace_unclipped(&self, p: DVec3, d: DVec3, end: End) -> RayState {
        self.trace_opts(p, d, end, false)
    }
}
