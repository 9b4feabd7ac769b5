#[path = "../tests/common/mod.rs"]
mod common;
use psf_engine::psf::{psf, Method, PsfOptions};
fn rel_l2(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}
fn main() {
    let lens = common::cooke();
    let r = common::read_json("cooke_triplet_reference.json");
    for pf in r["per_field"].as_array().unwrap() {
        let field = pf["field_deg"].as_f64().unwrap();
        let o = |m, n| PsfOptions { method: m, pixel_mm: 0.25e-3, size: 128, pupil_samples: n, ..Default::default() };
        let f = psf(&lens, field, 550.0, &o(Method::Fft, 128)).unwrap();
        let h = psf(&lens, field, 550.0, &o(Method::Huygens, 128)).unwrap();
        println!("field {field}: relL2 {:.4} strehl fft {:.4} huy {:.4} ref fft {:.4} huy {:.4}  t_fft {:.3} t_h {:.3} order {} ",
            rel_l2(&f.data, &h.data), f.strehl, h.strehl, pf["strehl_0p55_fft_pupil128_grid256"], pf["strehl_0p55_huygens_pupil128_image128"],
            f.diagnostics.values["time_s"], h.diagnostics.values["time_s"], f.diagnostics.values["distortion_order"]);
    }
}
