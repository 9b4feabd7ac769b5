//! First-order (paraxial) analysis by y-nu tracing: EFL, BFL, f-number, entrance and exit
//! pupils. Paraxial curvature of an even asphere includes its r^2 term (c + 2 a2).
//! EFL, BFL, FFL and the f-number (EFL / EPD) are properties of the lens whatever the
//! object distance; the image position and height follow the object (finite or not).

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
    /// Paraxial image height of the largest field: EFL * tan(max field) for an object at
    /// infinity, the chief ray's height at the paraxial image of a finite object.
    pub image_height: f64,
    /// Paraxial image of the object (the focus for an object at infinity) minus the image
    /// plane position.
    pub back_focus_shift: f64,
    /// Object plane to entrance pupil (mm); infinite for an object at infinity.
    pub object_to_pupil: f64,
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
    // Afocal (a window, a beam expander): the marginal ray leaves parallel. EFL, BFL, FFL,
    // f-number and image height are infinite; the pupils and the real trace are as usual.
    let afocal = nua.abs() < 1e-15;
    if afocal && matches!(lens.aperture, Aperture::FNumber(_)) {
        return Err(EngineError::Lens(
            "afocal system (EFL infinite): an F-number aperture gives no pupil; give the EPD".into(),
        ));
    }
    let efl = if afocal { f64::INFINITY } else { -1.0 / nua };
    let ua = nua / nk;
    let bfl = if afocal { f64::INFINITY } else { -ya / ua };
    // Front focal point: an object ray (y0, u0) leaves parallel when y0*A + u0*B = 0.
    let ffl = if afocal { f64::INFINITY } else { b[k - 1].1 / nua };
    let (ysa, ysb) = (a[lens.stop].0, b[lens.stop].0);
    if ysa.abs() < 1e-15 {
        return Err(EngineError::Lens(format!(
            "surface {} (stop) is at a paraxial image of the object: no entrance pupil",
            lens.stop + 1
        )));
    }
    let entrance_pupil_z = ysb / ysa;
    let d_obj = lens.object_distance;
    let object_to_pupil = entrance_pupil_z + d_obj;
    if d_obj.is_finite() && object_to_pupil.abs() < 1e-9 {
        return Err(EngineError::Lens(
            "the entrance pupil lies in the object plane: no beam can be defined from an object point".into(),
        ));
    }
    let epd = match lens.aperture {
        Aperture::Epd(d) => d,
        Aperture::FNumber(f) => efl.abs() / f,
        // the paraxially aimed marginal ray from the axial object point to the pupil's
        // rim leaves at u with n sin(u) = NA
        Aperture::ObjectNA(na) => 2.0 * object_to_pupil.abs() * (na / n[0]).asin().tan(),
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
    let (b_y, b_nu) = b[k - 1];
    let (image_dist, image_height) = if d_obj.is_finite() {
        // axial marginal ray (y0, u0) = (d u, u) = d a + b; chief ray of the largest field
        // from object height -L tan(t) at slope tan(t): (y0, u0) = tan(t) (-z_ep, 1)
        let (y, nu) = (d_obj * ya + b_y, d_obj * nua + b_nu);
        if nu.abs() < 1e-15 {
            (f64::INFINITY, f64::INFINITY)
        } else {
            let t = -y * nk / nu;
            let tan_t = lens.max_field_deg().to_radians().tan();
            let h = tan_t * (-entrance_pupil_z * (ya + ua * t) + (b_y + b_nu / nk * t));
            (t, if lens.max_field_deg() == 0.0 { 0.0 } else { h })
        }
    } else {
        (
            bfl,
            if lens.max_field_deg() == 0.0 {
                0.0
            } else {
                efl * lens.max_field_deg().to_radians().tan()
            },
        )
    };
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
        image_height,
        back_focus_shift: last_z + image_dist - image_z,
        object_to_pupil: if d_obj.is_finite() {
            object_to_pupil
        } else {
            f64::INFINITY
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Aiming, Beam, End, System};

    fn window(aperture: &str) -> Lens {
        Lens::from_json(&format!(
            r#"{{"name": "window", "aperture": {aperture}, "fields_deg": [0, 10], "wavelengths_nm": [587.5618],
                "surfaces": [{{"radius": "inf", "thickness": 5, "material": {{"n": 1.5}}, "stop": true}},
                             {{"radius": "inf", "thickness": 20, "material": "air"}}]}}"#
        ))
        .unwrap()
    }

    #[test]
    fn a_window_is_afocal_with_infinite_efl_and_traces() {
        let lens = window(r#"{"type": "epd", "value": 4}"#);
        let p = paraxial(&lens, 587.5618).unwrap();
        assert!(p.efl.is_infinite() && p.bfl.is_infinite() && p.f_number.is_infinite());
        assert_eq!((p.epd, p.stop_semi_diameter, p.entrance_pupil_z), (4.0, 2.0, 0.0));
        // A real ray at 10 deg leaves parallel to itself, shifted by a plate's closed-form
        // lateral offset t sin(a) (1 - cos(a) / (n cos(a'))).
        let sys = System::new(&lens, 587.5618).unwrap();
        let beam = Beam::new(&sys, 10.0, Aiming::Real).unwrap();
        let l = beam.launch(0.0, 0.0);
        let r = sys.trace(l.origin, beam.dir, End::Image);
        assert!(r.ok() && (r.d - beam.dir).length() < 1e-14);
        let a = 10f64.to_radians();
        let a2 = (a.sin() / 1.5).asin();
        let shift = 5.0 * a.sin() * (1.0 - a.cos() / (1.5 * a2.cos()));
        let straight = l.origin + ((25.0 - l.origin.z) / beam.dir.z) * beam.dir;
        assert!(
            ((straight.y - r.p.y) * a.cos() - shift).abs() < 1e-12,
            "{} vs {shift}",
            (straight.y - r.p.y) * a.cos()
        );
        // An F-number cannot size the pupil of an afocal system: one clear error.
        let e = paraxial(&window(r#"{"type": "fno", "value": 4}"#), 587.5618)
            .unwrap_err()
            .to_string();
        assert!(e.contains("afocal") && e.contains("EPD"), "{e}");
    }
}
