//! A curved image surface (a curved sensor) in the wave-optics analyses.
//!
//! Ray traces end on the sphere itself (kernel::step_image). The PSF, the wavefront and the
//! image irradiance of one field are computed in the plane perpendicular to the axis
//! through the point where that field's chief ray (primary wavelength) meets the sphere,
//! as OpticStudio computes its FFT PSF in a plane through the chief ray's image point.
//! Across a PSF window of half-width w at image height h that plane departs from the
//! sphere by about c h w (the sensor's tilt there times w): a defocus that grows towards
//! the window's edge, small where c h w is small against the depth of focus.

use std::borrow::Cow;

use crate::aim::{Aiming, Beam};
use crate::error::{EngineError, Result};
use crate::lens::Lens;
use crate::trace::{End, System};

/// `lens` itself for a flat image; else a copy whose flat image plane lies at the chief
/// ray's point on the curved surface at `field_deg`.
pub fn flat_at_field(lens: &Lens, field_deg: f64, aiming: Aiming) -> Result<Cow<'_, Lens>> {
    if lens.image_curvature == 0.0 {
        return Ok(Cow::Borrowed(lens));
    }
    let sys = System::new(lens, lens.primary_nm)?;
    let beam = Beam::new(&sys, field_deg, aiming)?;
    let chief = beam.launch(0.0, 0.0);
    let hit = sys.trace(chief.origin, chief.dir, End::Image);
    if !(chief.ok && hit.ok()) {
        return Err(EngineError::Trace(format!(
            "curved image: the chief ray at {field_deg} deg does not reach the image surface ({:?} at surface {})",
            hit.status,
            hit.surface + 1
        )));
    }
    let shift = hit.p.z - lens.image_z;
    let mut flat = lens.clone();
    flat.image_curvature = 0.0;
    flat.image_z += shift;
    if let Some(last) = flat.surfaces.last_mut() {
        last.thickness += shift;
    }
    Ok(Cow::Owned(flat))
}
