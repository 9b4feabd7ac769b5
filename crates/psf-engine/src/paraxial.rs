//! First-order (paraxial) analysis by y-nu tracing: EFL, BFL, f-number, entrance and exit
//! pupils. Paraxial curvature of an even asphere includes its r^2 term (c + 2 a2).

use crate::error::{EngineError, Result};
use crate::lens::{Aperture, Lens};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Paraxial {
    pub wavelength_nm: f64,
    pub efl: f64,
    /// Last vertex to the paraxial focus.
    pub bfl: f64,
    /// First vertex to the front focal point (signed, negative = in front).
    pub ffl: f64,
    /// Image-space paraxial f-number, EFL / EPD.
    pub f_number: f64,
    pub epd: f64,
    /// Entrance pupil position relative to the first vertex.
    pub entrance_pupil_z: f64,
    pub xpd: f64,
    /// Exit pupil position relative to the image plane.
    pub exit_pupil_z: f64,
    /// Paraxial semi-diameter of the stop that the EPD implies.
    pub stop_semi_diameter: f64,
    pub total_track: f64,
    pub image_z: f64,
    /// EFL * tan(max field).
    pub image_height: f64,
    /// Paraxial focus minus image plane position.
    pub back_focus_shift: f64,
}

/// (y, n u) after each surface for a ray starting at the first vertex with height y0 and
/// reduced angle nu0 (object space is air).
fn ynu(lens: &Lens, n: &[f64], y0: f64, u0: f64) -> Vec<(f64, f64)> {
    let mut y = y0;
    let mut nu = n[0] * u0;
    let mut out = Vec::with_capacity(lens.surfaces.len());
    for (i, s) in lens.surfaces.iter().enumerate() {
        let c = s.curvature + 2.0 * s.aspheric[0];
        nu -= y * c * (n[i + 1] - n[i]);
        out.push((y, nu));
        y += s.thickness * nu / n[i + 1];
    }
    out
}

pub fn paraxial(lens: &Lens, wavelength_nm: f64) -> Result<Paraxial> {
    let n = lens.indices(wavelength_nm)?;
    let k = lens.surfaces.len();
    let nk = n[k];
    let last = &lens.surfaces[k - 1];
    // Ray a: parallel to the axis at unit height. Ray b: through the first vertex at unit angle.
    let a = ynu(lens, &n, 1.0, 0.0);
    let b = ynu(lens, &n, 0.0, 1.0);
    let (ya, nua) = a[k - 1];
    if nua.abs() < 1e-15 {
        return Err(EngineError::Lens("afocal system: the paraxial marginal ray leaves parallel (EFL infinite)".into()));
    }
    let efl = -1.0 / nua;
    let ua = nua / nk;
    let bfl = -ya / ua;
    // Front focal point: an object ray (y0, u0) leaves parallel when y0*A + u0*B = 0.
    let ffl = b[k - 1].1 / nua;
    let (ysa, ysb) = (a[lens.stop].0, b[lens.stop].0);
    if ysa.abs() < 1e-15 {
        return Err(EngineError::Lens(format!(
            "surface {} (stop) is at a paraxial image of the object: no entrance pupil",
            lens.stop + 1
        )));
    }
    let entrance_pupil_z = ysb / ysa;
    let epd = match lens.aperture {
        Aperture::Epd(d) => d,
        Aperture::FNumber(f) => efl.abs() / f,
    };
    let stop_semi_diameter = 0.5 * epd * ysa.abs();
    // Chief ray: crosses the axis at the entrance pupil, unit angle.
    let chief = ynu(lens, &n, -entrance_pupil_z, 1.0);
    let (yc, nuc) = chief[k - 1];
    let last_z = last.z;
    let (exit_pupil_abs, xpd) = if nuc.abs() < 1e-15 {
        (f64::INFINITY, f64::INFINITY)
    } else {
        let zx = last_z - yc / (nuc / nk);
        let ym = 0.5 * epd * (ya + ua * (zx - last_z));
        (zx, 2.0 * ym.abs())
    };
    let image_z = lens.image_z;
    Ok(Paraxial {
        wavelength_nm,
        efl,
        bfl,
        ffl,
        f_number: efl.abs() / epd,
        epd,
        entrance_pupil_z,
        xpd,
        exit_pupil_z: exit_pupil_abs - image_z,
        stop_semi_diameter,
        total_track: lens.total_track(),
        image_z,
        image_height: efl * lens.max_field_deg().to_radians().tan(),
        back_focus_shift: last_z + bfl - image_z,
    })
}
