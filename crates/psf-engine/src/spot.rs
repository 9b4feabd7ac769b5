//! Spot diagrams and relative illumination on a polar midpoint grid: ring i of `rings`
//! sits at radius (i - 1/2)/rings with 6(2i - 1) rays, so every ray stands for the same
//! pupil area and sums over the pupil converge as 1/rings^2 (a hexapolar grid with rays on
//! the rim converges as 1/rings).

use crate::aim::{Aiming, Beam};
use crate::error::{EngineError, Result};
use crate::lens::Lens;
use crate::trace::{End, System};
use glam::{DVec2, DVec3};

pub fn polar_grid(rings: usize) -> (Vec<f64>, Vec<f64>) {
    let (mut px, mut py) = (vec![], vec![]);
    for i in 1..=rings {
        let r = (i as f64 - 0.5) / rings as f64;
        let k = 6 * (2 * i - 1);
        let phase = if i % 2 == 0 { 0.5 } else { 0.0 };
        for q in 0..k {
            let a = 2.0 * std::f64::consts::PI * (q as f64 + phase) / k as f64;
            px.push(r * a.cos());
            py.push(r * a.sin());
        }
    }
    (px, py)
}

#[derive(Clone, Debug, Default)]
pub struct Spot {
    /// Image-plane points (x, y) of transmitted rays, and their flux weights.
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub w: Vec<f64>,
    pub chief_x: f64,
    pub chief_y: f64,
    /// Transmitted flux (mm^2 of entrance pupil projected on the beam).
    pub flux: f64,
    pub launched: usize,
}

/// What spots of `rings` rings at `n_wavelengths` wavelengths allocate: per ray its launch,
/// its traced state and its kept image point (about 160 bytes); 6 rings^2 rays each.
pub fn spot_memory(rings: usize, n_wavelengths: usize) -> crate::budget::Need {
    let rays = 6.0 * (rings as f64).powi(2);
    crate::budget::Need(vec![(
        format!("{rays:.3e} rays x {n_wavelengths} wavelengths"),
        rays * n_wavelengths as f64 * 160.0,
    )])
}

pub fn trace_spot(lens: &Lens, field_deg: f64, wavelength_nm: f64, rings: usize, aiming: Aiming) -> Result<Spot> {
    spot_memory(rings, 1).check(&format!("a {rings}-ring spot"))?;
    let sys = System::new(lens, wavelength_nm)?;
    let beam = Beam::new(&sys, field_deg, aiming)?;
    let c = beam.launch(0.0, 0.0);
    let chief = sys.trace(c.origin, c.dir, End::Image);
    let (px, py) = polar_grid(rings);
    let (launches, rays) = beam.trace_pupil(&px, &py);
    let mut s = Spot {
        chief_x: chief.p.x,
        chief_y: chief.p.y,
        launched: px.len(),
        ..Default::default()
    };
    let cell = std::f64::consts::PI / px.len() as f64;
    for (l, r) in launches.iter().zip(&rays) {
        if r.ok() {
            let w = beam.flux_weight(l) * cell;
            s.x.push(r.p.x);
            s.y.push(r.p.y);
            s.w.push(w);
            s.flux += w;
        }
    }
    if !chief.ok() && s.w.is_empty() {
        return Err(EngineError::Trace(format!(
            "no ray reaches the image at {field_deg} deg, {wavelength_nm} nm"
        )));
    }
    Ok(s)
}

/// Weighted RMS radius about the common centroid of several spots (mm).
pub fn rms_radius(spots: &[(&Spot, f64)]) -> f64 {
    let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
    for (s, wt) in spots {
        let norm = wt / s.flux.max(1e-300);
        for i in 0..s.x.len() {
            sx += norm * s.w[i] * s.x[i];
            sy += norm * s.w[i] * s.y[i];
            sw += norm * s.w[i];
        }
    }
    let (cx, cy) = (sx / sw, sy / sw);
    let mut v = 0.0;
    for (s, wt) in spots {
        let norm = wt / s.flux.max(1e-300);
        for i in 0..s.x.len() {
            v += norm * s.w[i] * ((s.x[i] - cx).powi(2) + (s.y[i] - cy).powi(2));
        }
    }
    (v / sw).sqrt()
}

/// Field steps (from the axis to the largest field) and pupil grid side of `field_fold`.
pub const FOLD_FIELDS: usize = 40;
pub const FOLD_PUPIL: usize = 15;

/// Where the image of the field folds: a pupil point whose image height does not grow
/// with the field angle between two neighbouring fields.
#[derive(Debug, Clone, PartialEq)]
pub struct Fold {
    /// The outer field of the step (deg).
    pub field_deg: f64,
    /// The pupil point (normalized entrance-pupil coordinates).
    pub px: f64,
    pub py: f64,
    /// Its image height's change over the step, against the field's direction (mm; <= 0).
    pub step_mm: f64,
}

/// Whether the image of the field folds between the axis and `field_max_deg`: for each
/// point of a 15 x 15 pupil grid, the meridional image height of its ray must grow with the
/// field angle (41 fields), in the direction the chief ray's does. Where some pupil zone's
/// does not, rays of different fields cross and light from far fields lands on a point by
/// another branch of the mapping; the irradiance of `irradiance` (one Newton branch per pupil
/// point) then misses it: on sampled designs of a wide space that fold this way it was 0.6 to
/// 7 times a flux count's (docs/accuracy.md, "Relative illumination of folded designs").
/// Returns the worst step, None when the mapping is one-to-one at this sampling.
pub fn field_fold(lens: &Lens, field_max_deg: f64, wavelength_nm: f64, aiming: Aiming) -> Result<Option<Fold>> {
    let sys = System::new(lens, wavelength_nm)?;
    let (mut px, mut py) = (vec![], vec![]);
    for i in 0..FOLD_PUPIL {
        for j in 0..FOLD_PUPIL {
            let x = -1.0 + 2.0 * i as f64 / (FOLD_PUPIL - 1) as f64;
            let y = -1.0 + 2.0 * j as f64 / (FOLD_PUPIL - 1) as f64;
            if x * x + y * y <= 1.0 + 1e-12 {
                px.push(x);
                py.push(y);
            }
        }
    }
    let heights = |f: f64| -> Result<Vec<Option<f64>>> {
        let beam = Beam::new(&sys, f, aiming)?;
        let launches = beam.launches(&px, &py);
        let origins: Vec<DVec3> = launches.iter().map(|l| l.origin).collect();
        let dirs: Vec<DVec3> = launches.iter().map(|l| l.dir).collect();
        let hits = sys.trace_many(&origins, &dirs);
        Ok(launches
            .iter()
            .zip(&hits)
            .map(|(l, h)| (l.ok && h.ok()).then_some(h.p.y))
            .collect())
    };
    // the direction the image grows in: the chief ray's, from the axis to the largest field
    let beam = Beam::new(&sys, field_max_deg, aiming)?;
    let c = beam.launch(0.0, 0.0);
    let chief = sys.trace(c.origin, c.dir, End::Image);
    if !(c.ok && chief.ok()) || field_max_deg == 0.0 {
        return Ok(None); // nothing to fold (or the chief ray's own trace reports it elsewhere)
    }
    let sign = if chief.p.y >= 0.0 { 1.0 } else { -1.0 };
    let mut prev = heights(0.0)?;
    let mut worst: Option<Fold> = None;
    for k in 1..=FOLD_FIELDS {
        let f = field_max_deg * k as f64 / FOLD_FIELDS as f64;
        let y = heights(f)?;
        for i in 0..y.len() {
            if let (Some(a), Some(b)) = (prev[i], y[i]) {
                let step = sign * (b - a);
                if !(step > 0.0) && worst.as_ref().is_none_or(|w| step < w.step_mm) {
                    worst = Some(Fold {
                        field_deg: f,
                        px: px[i],
                        py: py[i],
                        step_mm: step,
                    });
                }
            }
        }
        prev = y;
    }
    Ok(worst)
}

/// The chief ray's status code (`trace::Status`, 0-4) at each field (outer) and wavelength
/// (inner), or the error where its beam cannot be launched (a wavelength the glass does not
/// cover, a field the aiming cannot reach): what a design check needs of every field at once.
pub fn chief_ray_status(lens: &Lens, fields_deg: &[f64], wavelengths_nm: &[f64], aiming: Aiming) -> Vec<Result<u8>> {
    let systems: Vec<Result<System>> = wavelengths_nm.iter().map(|&wl| System::new(lens, wl)).collect();
    let mut out = Vec::with_capacity(fields_deg.len() * wavelengths_nm.len());
    for &f in fields_deg {
        for sys in &systems {
            out.push(match sys {
                Err(e) => Err(e.clone()),
                Ok(sys) => Beam::new(sys, f, aiming).map(|b| b.trace_pupil_soa(&[0.0], &[0.0]).status[0]),
            });
        }
    }
    out
}

/// Rings of the midpoint pupil grid where vignetting cuts the pupil (the edge must be
/// resolved; the clear beam uses the Gauss grid of `gauss_pupil`).
pub const RI_RINGS: usize = 24;

/// Direction-cosine step of the Jacobian's central differences.
pub(crate) const RI_STEP: f64 = 1e-5;

/// Pupil points (x, y) and weights (summing to pi, the unit disc's area) of a product
/// quadrature: Gauss-Legendre in r^2 (4 nodes) times 12 equally spaced angles, exact for
/// polynomials of degree 7 in r^2 and 11 in angle. A clear beam's integrand (1 / |det J|)
/// is smooth over the pupil: it agrees with a 64-ring midpoint grid to ~3e-7. The field
/// lies along +y in a rotationally symmetric lens, so the integrand is even in x: only the
/// x > 0 half is kept, at twice the weight (the 12 angles pair up as a and pi - a).
pub fn gauss_pupil() -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    const X: [f64; 4] = [
        -0.861_136_311_594_052_6,
        -0.339_981_043_584_856_3,
        0.339_981_043_584_856_3,
        0.861_136_311_594_052_6,
    ];
    const W: [f64; 4] = [
        0.347_854_845_137_453_9,
        0.652_145_154_862_546_1,
        0.652_145_154_862_546_1,
        0.347_854_845_137_453_9,
    ];
    const N_ANGLES: usize = 12;
    let (mut px, mut py, mut pw) = (vec![], vec![], vec![]);
    for (x, w) in X.iter().zip(W) {
        let r = (0.5 * (1.0 + x)).sqrt();
        for q in 0..N_ANGLES {
            let a = 2.0 * std::f64::consts::PI * (q as f64 + 0.5) / N_ANGLES as f64;
            if a.cos() <= 0.0 {
                continue;
            }
            px.push(r * a.cos());
            py.push(r * a.sin());
            // area element r dr da = d(r^2)/2 da: (w/2 on [0, 1]) x (2 pi / N) / 2, doubled
            pw.push(w * std::f64::consts::PI / N_ANGLES as f64);
        }
    }
    (px, py, pw)
}

/// The pupil grid of `irradiance`.
#[derive(Clone, Copy, Debug)]
pub enum PupilGrid {
    /// `gauss_pupil`, and a ring of rays on the pupil's rim whose loss says "vignetted".
    Clear,
    /// The polar midpoint grid of `polar_grid` with this many rings.
    Rings(usize),
}

impl PupilGrid {
    /// The grid's pupil points (px, py) and area weights.
    pub fn points(self) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        match self {
            PupilGrid::Clear => gauss_pupil(),
            PupilGrid::Rings(r) => {
                // the grid is mirror symmetric in x (as the integrand is): the x > 0 half at
                // twice the weight, the points on x = 0 once
                let (x, y) = polar_grid(r);
                let cell = std::f64::consts::PI / x.len() as f64;
                let keep: Vec<(f64, f64, f64)> = x
                    .iter()
                    .zip(&y)
                    .filter(|(x, _)| **x > -1e-12)
                    .map(|(&x, &y)| (x, y, if x > 1e-12 { 2.0 * cell } else { cell }))
                    .collect();
                (
                    keep.iter().map(|p| p.0).collect(),
                    keep.iter().map(|p| p.1).collect(),
                    keep.iter().map(|p| p.2).collect(),
                )
            }
        }
    }
}

/// Image irradiance at the image point of the chief ray of a field, for a uniform
/// Lambertian object at infinity of unit radiance (object-space index 1), in flux per mm^2
/// of image per unit radiance, and whether every pupil ray passed.
///
/// A pupil point q (entrance-pupil plane, area dA) and a direction (L, M) carry the flux
/// dA dL dM (etendue). The rays through q reaching the image point P come from the
/// direction where Y(q, L, M) = P, with density 1 / |det d(X, Y)/d(L, M)| per image area,
/// so E(P) = sum over transmitted q of dA / |det J_q|. J_q comes from central differences
/// of unclipped rays; the direction is corrected by one Newton step from the beam's to the
/// one that lands on P (it differs by the blur over the focal length, so defocus and the
/// vignetting edge seen from P are taken into account), and that ray decides whether q
/// transmits. Valid at any image-plane position: no paraxial quantity enters.
pub fn irradiance(
    lens: &Lens,
    field_deg: f64,
    wavelength_nm: f64,
    grid: PupilGrid,
    aiming: Aiming,
) -> Result<(f64, bool)> {
    let flat = crate::image::flat_at_field(lens, field_deg, aiming)?;
    let lens: &Lens = &flat;
    let sys = System::new(lens, wavelength_nm)?;
    let mut open = System::new(lens, wavelength_nm)?;
    open.clip = false;
    let beam = Beam::new(&sys, field_deg, aiming)?;
    let (px, py, pw) = grid.points();
    let mut all_pass = true;
    if let PupilGrid::Clear = grid {
        // the rim's x >= 0 half (the other is its mirror image): 19 rays, 10 deg apart
        let rim: (Vec<f64>, Vec<f64>) = (0..=18)
            .map(|q| (std::f64::consts::PI * (q as f64 / 18.0 - 0.5)).sin_cos())
            .map(|(s, c)| (c, s))
            .unzip();
        let (rl, rr) = beam.trace_pupil(&rim.0, &rim.1);
        all_pass = rl.iter().zip(&rr).all(|(l, r)| l.ok && r.ok());
    }
    let launches = beam.launches(&px, &py);
    let c = beam.launch(0.0, 0.0);
    let chief = open.trace(c.origin, c.dir, End::Image);
    // directions about each launch's own (one direction from infinity; from a finite
    // object a uniform Lambertian object plane sends the same radiance along every ray,
    // so the same etendue sum holds)
    let dir = |d0: DVec3, dl: f64, dm: f64| {
        DVec3::new(
            d0.x + dl,
            d0.y + dm,
            (1.0 - (d0.x + dl).powi(2) - (d0.y + dm).powi(2)).max(0.0).sqrt(),
        )
    };
    let steps = [
        (0.0, 0.0),
        (RI_STEP, 0.0),
        (-RI_STEP, 0.0),
        (0.0, RI_STEP),
        (0.0, -RI_STEP),
    ];
    let (mut origins, mut dirs) = (Vec::with_capacity(5 * px.len()), Vec::with_capacity(5 * px.len()));
    for l in &launches {
        for &(a, b) in &steps {
            let d = dir(l.dir, a, b);
            origins.push(beam.origin_along(l, d));
            dirs.push(d);
        }
    }
    let geo = open.trace_many(&origins, &dirs);
    // Newton step of each pupil point's direction onto the image point P.
    let target = chief.ok().then_some(DVec2::new(chief.p.x, chief.p.y));
    let (mut co, mut cd, mut w) = (vec![], vec![], vec![]);
    for (i, l) in launches.iter().enumerate() {
        let g = &geo[5 * i..5 * i + 5];
        if !l.ok || g.iter().any(|r| !r.ok()) {
            all_pass = false;
            continue;
        }
        let j = [
            [
                (g[1].p.x - g[2].p.x) / (2.0 * RI_STEP),
                (g[3].p.x - g[4].p.x) / (2.0 * RI_STEP),
            ],
            [
                (g[1].p.y - g[2].p.y) / (2.0 * RI_STEP),
                (g[3].p.y - g[4].p.y) / (2.0 * RI_STEP),
            ],
        ];
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.abs() > 1e-300) {
            all_pass = false;
            continue;
        }
        let (dl, dm) = match target {
            Some(t) => {
                let r = DVec2::new(t.x - g[0].p.x, t.y - g[0].p.y);
                (
                    (j[1][1] * r.x - j[0][1] * r.y) / det,
                    (-j[1][0] * r.x + j[0][0] * r.y) / det,
                )
            }
            None => (0.0, 0.0),
        };
        let d = dir(l.dir, dl, dm);
        co.push(beam.origin_along(l, d));
        cd.push(d);
        w.push(l.area * pw[i] / det.abs());
    }
    let landed = sys.trace_many(&co, &cd);
    let mut e = 0.0;
    for (r, wi) in landed.iter().zip(&w) {
        if r.ok() {
            e += wi;
        } else {
            all_pass = false;
        }
    }
    Ok((e, all_pass && w.len() == launches.len()))
}

/// Irradiance with the grid the beam needs: the coarse grid with the rim where every ray
/// passes, the fine grid where vignetting cuts the pupil.
pub fn irradiance_adaptive(lens: &Lens, field_deg: f64, wavelength_nm: f64, aiming: Aiming) -> Result<f64> {
    let (e, clear) = irradiance(lens, field_deg, wavelength_nm, PupilGrid::Clear, aiming)?;
    if clear {
        return Ok(e);
    }
    Ok(irradiance(lens, field_deg, wavelength_nm, PupilGrid::Rings(RI_RINGS), aiming)?.0)
}

/// Image irradiance at a field relative to the axis (`irradiance` at the chief ray's image
/// point over the same on the axis): the flux through the real pupil per unit image area,
/// so the cos^4 law, distortion, pupil aberration, vignetting and defocus all come out of
/// the trace. `axis`: the on-axis irradiance where the caller has it.
pub fn relative_illumination_from(
    lens: &Lens,
    field_deg: f64,
    wavelength_nm: f64,
    aiming: Aiming,
    axis: Option<f64>,
) -> Result<f64> {
    if afocal(lens)? {
        return Err(EngineError::Trace(
            "relative illumination is not defined for an afocal system: it forms no image of an object at infinity"
                .into(),
        ));
    }
    let e0 = match axis {
        Some(e) => e,
        None => irradiance_adaptive(lens, 0.0, wavelength_nm, aiming)?,
    };
    if !(e0 > 0.0) {
        return Err(EngineError::Trace(format!(
            "no on-axis ray reaches the image at {wavelength_nm} nm"
        )));
    }
    if field_deg == 0.0 {
        return Ok(1.0);
    }
    Ok(irradiance_adaptive(lens, field_deg, wavelength_nm, aiming)? / e0)
}

/// Whether the lens is afocal (infinite paraxial focal length at its primary wavelength).
pub fn afocal(lens: &Lens) -> Result<bool> {
    Ok(!crate::paraxial::paraxial(lens, lens.primary_nm)?.efl.is_finite())
}

/// Relative illumination at one field and wavelength (see `relative_illumination_from`);
/// `rings` sets the pupil grid (the adaptive choice where 0).
pub fn relative_illumination(
    lens: &Lens,
    field_deg: f64,
    wavelength_nm: f64,
    rings: usize,
    aiming: Aiming,
) -> Result<f64> {
    if rings == 0 {
        return relative_illumination_from(lens, field_deg, wavelength_nm, aiming, None);
    }
    let e0 = irradiance(lens, 0.0, wavelength_nm, PupilGrid::Rings(rings), aiming)?.0;
    if !(e0 > 0.0) {
        return Err(EngineError::Trace(format!(
            "no on-axis ray reaches the image at {wavelength_nm} nm"
        )));
    }
    Ok(irradiance(lens, field_deg, wavelength_nm, PupilGrid::Rings(rings), aiming)?.0 / e0)
}

/// Polychromatic spot summary for one field: RMS radius about the common centroid,
/// per-wavelength RMS, vignetting and relative illumination (wavelength-weighted).
pub fn spot_summary(
    lens: &Lens,
    field_deg: f64,
    wavelengths_nm: &[f64],
    weights: &[f64],
    rings: usize,
    aiming: Aiming,
) -> Result<serde_json::Value> {
    spot_memory(rings, wavelengths_nm.len())
        .check(&format!("a {rings}-ring spot at {} wavelengths", wavelengths_nm.len()))?;
    let spots = wavelengths_nm
        .iter()
        .map(|&wl| trace_spot(lens, field_deg, wl, rings, aiming))
        .collect::<Result<Vec<_>>>()?;
    let pairs: Vec<(&Spot, f64)> = spots
        .iter()
        .zip(weights.iter().copied())
        .filter(|(s, _)| s.flux > 0.0)
        .collect();
    if pairs.is_empty() {
        return Err(EngineError::Trace(format!(
            "no ray reaches the image at {field_deg} deg"
        )));
    }
    let wsum: f64 = weights.iter().sum();
    let mut vig = 0.0;
    let mut ri = 0.0;
    // an afocal system forms no image: no relative illumination (null)
    let no_image = afocal(lens)?;
    let mut per = vec![];
    for ((s, &w), &wl) in spots.iter().zip(weights).zip(wavelengths_nm) {
        per.push(if s.flux > 0.0 {
            rms_radius(&[(s, 1.0)]) * 1e3
        } else {
            f64::NAN
        });
        vig += w / wsum * s.x.len() as f64 / s.launched as f64;
        if !no_image {
            ri += w / wsum * relative_illumination(lens, field_deg, wl, 0, aiming)?;
        }
    }
    let (n_ok, n_rays): (usize, usize) = (
        spots.iter().map(|s| s.x.len()).sum(),
        spots.iter().map(|s| s.launched).sum(),
    );
    let cx: f64 = pairs
        .iter()
        .map(|(s, w)| w * s.x.iter().zip(&s.w).map(|(x, q)| x * q).sum::<f64>() / s.flux)
        .sum::<f64>()
        / pairs.iter().map(|p| p.1).sum::<f64>();
    let cy: f64 = pairs
        .iter()
        .map(|(s, w)| w * s.y.iter().zip(&s.w).map(|(y, q)| y * q).sum::<f64>() / s.flux)
        .sum::<f64>()
        / pairs.iter().map(|p| p.1).sum::<f64>();
    let primary = spots.get(wavelengths_nm.len() / 2).unwrap_or(&spots[0]);
    Ok(serde_json::json!({
        "field_deg": field_deg,
        "rms_um": rms_radius(&pairs) * 1e3,
        "rms_um_per_wavelength": per.into_iter().map(|v| if v.is_finite() { serde_json::json!(v) } else { serde_json::Value::Null }).collect::<Vec<_>>(),
        "centroid_x_mm": cx, "centroid_y_mm": cy, "chief_y_mm": primary.chief_y,
        "n_rays": n_rays, "n_ok": n_ok, "vignetting": vig, "relative_illumination": if no_image { serde_json::Value::Null } else { serde_json::json!(ri) },
    }))
}
