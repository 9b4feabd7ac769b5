//! Real ray tracing of ray batches. Every ray ends with a status code instead of NaN:
//! it reached the image plane, missed a surface, was clipped by a clear aperture, or was
//! totally internally reflected; failed rays keep the index of the surface at fault.

use crate::error::Result;
use crate::kernel::{self, Block, ImageConst, Plan, Ray, SurfConst, LANES};
use crate::lens::Lens;
use glam::DVec3;
use rayon::prelude::*;

// The status codes are the kernel's; callers name them from here.
pub use crate::kernel::Status;

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
    fn arrived(r: &Ray) -> RayState {
        RayState {
            p: DVec3::new(r.x, r.y, r.z),
            d: DVec3::new(r.dx, r.dy, r.dz),
            opl: r.opl,
            status: Status::Ok,
            surface: -1,
        }
    }
    fn fail(status: Status, surface: usize) -> RayState {
        RayState {
            p: DVec3::ZERO,
            d: DVec3::ZERO,
            opl: 0.0,
            status,
            surface: surface as i32,
        }
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
    consts: Vec<SurfConst>,
    image: ImageConst,
}

/// Where a trace stops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum End {
    Image,
    /// Stop at the intersection with this surface (0-based), before refracting there.
    Surface(usize),
}

/// Blocks per rayon task at the least: enough work to amortize scheduling.
const MIN_BLOCKS_PER_TASK: usize = 8;

impl<'a> System<'a> {
    pub fn new(lens: &'a Lens, wavelength_nm: f64) -> Result<Self> {
        let n = lens.indices(wavelength_nm)?;
        let (consts, image) = kernel::constants(lens, &n);
        Ok(System {
            lens,
            wavelength_nm,
            n,
            clip: true,
            consts,
            image,
        })
    }

    pub fn image_index(&self) -> f64 {
        *self.n.last().unwrap()
    }

    fn plan(&self, end: End, clip: bool) -> Plan<'_> {
        let stop_at = match end {
            End::Image => None,
            End::Surface(i) => Some(i.min(self.consts.len() - 1)),
        };
        Plan {
            consts: &self.consts,
            surfaces: &self.lens.surfaces,
            image: &self.image,
            stop_at,
            clip,
        }
    }

    /// Trace one ray from `p` (global) along unit `d` in object space.
    #[inline]
    pub fn trace(&self, p: DVec3, d: DVec3, end: End) -> RayState {
        self.trace_opts(p, d, end, self.clip)
    }

    fn trace_opts(&self, p: DVec3, d: DVec3, end: End, clip: bool) -> RayState {
        let mut r = Ray {
            x: p.x,
            y: p.y,
            z: p.z,
            dx: d.x,
            dy: d.y,
            dz: d.z,
            opl: 0.0,
        };
        if !kernel::valid_input(&r) {
            return RayState::fail(Status::Invalid, 0);
        }
        let plan = self.plan(end, clip);
        for i in 0..plan.last() {
            let (sc, s) = (&self.consts[i], &self.lens.surfaces[i]);
            let st = kernel::step(sc, s, sc.kind, &mut r, clip, plan.refracts(i));
            if st != 0 {
                return RayState::fail(Status::from_code(st), i);
            }
        }
        if plan.stop_at.is_none() {
            let st = kernel::step_image(&self.image, &mut r, clip);
            if st != 0 {
                return RayState::fail(Status::from_code(st), self.consts.len());
            }
        }
        RayState::arrived(&r)
    }

    /// Trace a batch in parallel; output order matches input order.
    pub fn trace_many(&self, origins: &[DVec3], dirs: &[DVec3]) -> Vec<RayState> {
        self.trace_launched(origins.len(), |start, b| {
            for j in 0..b.len {
                b.set(j, origins[start + j].to_array(), dirs[start + j].to_array());
            }
        })
    }

    /// Trace `n` rays to the image in parallel blocks; `load(start, block)` fills lanes
    /// `0..block.len` with the rays from index `start` (`Block::set`).
    pub fn trace_launched<L>(&self, n: usize, load: L) -> Vec<RayState>
    where
        L: Fn(usize, &mut Block) + Sync,
    {
        let mut out = vec![RayState::fail(Status::Invalid, 0); n];
        let plan = self.plan(End::Image, self.clip);
        out.par_chunks_mut(LANES)
            .enumerate()
            .with_min_len(MIN_BLOCKS_PER_TASK)
            .for_each_init(Block::default, |b, (bi, chunk)| {
                b.reset(chunk.len());
                load(bi * LANES, b);
                kernel::run(&plan, b);
                b.write_states(chunk);
            });
        out
    }
}

/// Traced rays as flat arrays (struct of arrays), ready to hand to numpy without copying.
/// Failed rays have zero position, direction and optical path.
#[derive(Clone, Debug, Default)]
pub struct Traced {
    /// Row-major (n, 3) launch points.
    pub origin: Vec<f64>,
    /// Row-major (n, 3).
    pub position: Vec<f64>,
    /// Row-major (n, 3).
    pub direction: Vec<f64>,
    pub opl: Vec<f64>,
    /// Status codes (`Status as u8`).
    pub status: Vec<u8>,
    /// Surface of the failure (0-based, surfaces.len() = image plane), or -1.
    pub surface: Vec<i32>,
}

impl<'a> System<'a> {
    /// Trace `n` rays straight into flat output arrays, in parallel: `load(start, block)`
    /// fills lanes `0..block.len` with the rays from index `start` (`Block::set`).
    pub fn trace_soa<L>(&self, n: usize, end: End, load: L) -> Traced
    where
        L: Fn(usize, &mut Block) + Sync,
    {
        let plan = self.plan(end, self.clip);
        let mut t = Traced {
            origin: huge_pages(vec![0.0; 3 * n]),
            position: huge_pages(vec![0.0; 3 * n]),
            direction: huge_pages(vec![0.0; 3 * n]),
            opl: huge_pages(vec![0.0; n]),
            status: vec![0; n],
            surface: huge_pages(vec![0; n]),
        };
        t.origin
            .par_chunks_mut(3 * LANES)
            .zip(t.position.par_chunks_mut(3 * LANES))
            .zip(t.direction.par_chunks_mut(3 * LANES))
            .zip(t.opl.par_chunks_mut(LANES))
            .zip(t.status.par_chunks_mut(LANES))
            .zip(t.surface.par_chunks_mut(LANES))
            .enumerate()
            .with_min_len(MIN_BLOCKS_PER_TASK)
            .for_each_init(
                Block::default,
                |b, (bi, (((((org, pos), dir), opl), status), surface))| {
                    b.reset(opl.len());
                    load(bi * LANES, b);
                    for j in 0..b.len {
                        org[3 * j..3 * j + 3].copy_from_slice(&[b.x[j], b.y[j], b.z[j]]);
                    }
                    kernel::run(&plan, b);
                    for j in 0..b.len {
                        let ok = b.status[j] == 0;
                        status[j] = b.status[j];
                        surface[j] = if ok { -1 } else { b.surface[j] };
                        if ok {
                            pos[3 * j..3 * j + 3].copy_from_slice(&[b.x[j], b.y[j], b.z[j]]);
                            dir[3 * j..3 * j + 3].copy_from_slice(&[b.dx[j], b.dy[j], b.dz[j]]);
                            opl[j] = b.opl[j];
                        }
                    }
                },
            );
        t
    }
}

/// Ask the kernel to back a large, freshly allocated (not yet touched) output array with
/// transparent huge pages: a million rays write ~85 MB, and faulting that in 4 KiB pages
/// costs more than tracing them. Advice only; nothing changes where it is not honoured.
pub(crate) fn huge_pages<T>(v: Vec<T>) -> Vec<T> {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = v.len() * std::mem::size_of::<T>();
        if bytes >= 4 * HUGE {
            let start = (v.as_ptr() as usize).next_multiple_of(HUGE);
            let end = (v.as_ptr() as usize + bytes) / HUGE * HUGE;
            if end > start {
                // SAFETY: the range lies inside the vector's allocation; madvise only
                // changes how the kernel backs it, not its contents.
                unsafe { libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_HUGEPAGE) };
            }
        }
    }
    v
}

impl Block {
    /// The first `out.len()` lanes as RayStates (failed rays zeroed).
    pub fn write_states(&self, out: &mut [RayState]) {
        for (j, o) in out.iter_mut().enumerate() {
            let st = Status::from_code(self.status[j]);
            *o = if st == Status::Ok {
                RayState::arrived(&self.get(j))
            } else {
                RayState::fail(st, self.surface[j].max(0) as usize)
            };
        }
    }
}

impl<'a> System<'a> {
    /// Trace ignoring clear apertures (used for aiming probes).
    pub fn trace_unclipped(&self, p: DVec3, d: DVec3, end: End) -> RayState {
        self.trace_opts(p, d, end, false)
    }
}
