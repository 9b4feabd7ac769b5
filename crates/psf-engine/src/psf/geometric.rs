//! Geometric PSF: the spot diagram of a dense pupil grid, each ray's flux binned into the
//! output pixel it lands in (relative to the chief-ray image point).

use super::pupil::Pupil;
use super::{Diagnostics, PsfOptions};

pub fn geometric_psf(p: &Pupil, o: &PsfOptions, d: &mut Diagnostics) -> (Vec<f64>, f64) {
    let s = o.size;
    let h = (s / 2) as f64;
    let mut out = vec![0.0; s * s];
    let (mut cx, mut cy, mut wsum) = (0.0, 0.0, 0.0);
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        let dx = p.image[j].x - p.chief.x;
        let dy = p.image[j].y - p.chief.y;
        cx += p.flux[j] * dx;
        cy += p.flux[j] * dy;
        wsum += p.flux[j];
        let c = (dx / o.pixel_mm + h + 0.5).floor();
        let r = (dy / o.pixel_mm + h + 0.5).floor();
        if c >= 0.0 && r >= 0.0 && (c as usize) < s && (r as usize) < s {
            out[r as usize * s + c as usize] += p.flux[j];
        }
    }
    let (cx, cy) = (cx / wsum, cy / wsum);
    let mut var = 0.0;
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        let dx = p.image[j].x - p.chief.x - cx;
        let dy = p.image[j].y - p.chief.y - cy;
        var += p.flux[j] * (dx * dx + dy * dy);
    }
    let rms = (var / wsum).sqrt();
    // Airy radius from the working cone: 1.22 lambda / (2 NA), NA from the ray spread.
    let (mut lmin, mut lmax) = (f64::MAX, f64::MIN);
    for j in (0..p.valid.len()).filter(|&j| p.valid[j]) {
        lmin = lmin.min(p.l[j]);
        lmax = lmax.max(p.l[j]);
    }
    let na = 0.5 * (lmax - lmin) * p.n_image;
    let airy = if na > 0.0 {
        0.61 * p.wavelength_mm / na
    } else {
        f64::INFINITY
    };
    if rms < airy {
        d.warn(format!(
            "geometric PSF near the diffraction limit: RMS spot {:.2} um is smaller than the Airy radius {:.2} um; use method=fft or huygens",
            rms * 1e3,
            airy * 1e3
        ));
    }
    let sigma = p.rms_wavefront();
    d.set("rms_spot_um", rms * 1e3);
    d.set("airy_radius_um", airy * 1e3);
    d.set("rms_wavefront_waves", sigma);
    d.set("strehl_method", "marechal");
    let transmitted = p.transmitted_fraction();
    let window: f64 = out.iter().sum();
    d.set(
        "energy_in_window",
        if transmitted > 0.0 { window / transmitted } else { 0.0 },
    );
    (out, (-(2.0 * std::f64::consts::PI * sigma).powi(2)).exp())
}
