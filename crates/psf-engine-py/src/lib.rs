//! Thin PyO3 layer over psf-engine: converts arrays and errors, releases the GIL around
//! every engine call. All physics lives in the core crate.

use numpy::{IntoPyArray, PyArray1, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use psf_engine::psf::{Method, PsfOptions};
use psf_engine::{Aiming, EngineError as CoreError, Lens};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

pyo3::create_exception!(
    _engine,
    EngineError,
    PyException,
    "Base class of every error raised by the engine."
);
pyo3::create_exception!(
    _engine,
    LensError,
    EngineError,
    "Invalid prescription; names the surface and parameter."
);
pyo3::create_exception!(
    _engine,
    MaterialError,
    LensError,
    "Unusable material (bad coefficients, wavelength out of range)."
);
pyo3::create_exception!(
    _engine,
    TraceError,
    EngineError,
    "A trace that cannot produce a result."
);
pyo3::create_exception!(_engine, PsfError, EngineError, "A PSF that cannot be computed.");

fn to_py(e: CoreError) -> PyErr {
    let msg = e.to_string();
    match e {
        CoreError::Lens(_) => LensError::new_err(msg),
        CoreError::Material(_) => MaterialError::new_err(msg),
        CoreError::Trace(_) => TraceError::new_err(msg),
        CoreError::Psf(_) => PsfError::new_err(msg),
        CoreError::Argument(_) => pyo3::exceptions::PyValueError::new_err(msg),
    }
}

/// Run `f` on a thread of its own while this one calls `callback(done, total)` every
/// 0.2 s and checks for Ctrl-C; an interrupt asks the computation to stop and is re-raised.
fn watched<T: Send + 'static>(
    py: Python<'_>,
    o: &mut PsfOptions,
    callback: &Bound<'_, PyAny>,
    f: impl FnOnce(&PsfOptions) -> psf_engine::Result<T> + Send + 'static,
) -> PyResult<T> {
    use std::sync::atomic::Ordering::Relaxed;
    let prog = std::sync::Arc::new(psf_engine::psf::Progress::default());
    o.progress = Some(prog.clone());
    let job = o.clone();
    let (tx, rx) = std::sync::mpsc::channel();
    let rx = std::sync::Mutex::new(rx);
    std::thread::spawn(move || {
        let _ = tx.send(f(&job));
    });
    loop {
        match py.detach(|| {
            rx.lock()
                .expect("receiver")
                .recv_timeout(std::time::Duration::from_millis(200))
        }) {
            Ok(r) => return r.map_err(to_py),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                let step = callback
                    .call1((prog.done.load(Relaxed), prog.total.load(Relaxed)))
                    .and_then(|_| py.check_signals());
                if let Err(e) = step {
                    prog.cancel.store(true, Relaxed);
                    let _ = py.detach(|| rx.lock().expect("receiver").recv());
                    return Err(e);
                }
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                return Err(pyo3::exceptions::PyRuntimeError::new_err(
                    "psf: the computation thread ended without a result",
                ))
            }
        }
    }
}

/// Run `f` without the GIL and convert its error.
fn run<T: Send>(py: Python<'_>, f: impl FnOnce() -> psf_engine::Result<T> + Send) -> PyResult<T> {
    py.detach(f).map_err(to_py)
}

fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (v.to_string(),))
}

fn parse_lens(text: &str) -> psf_engine::Result<Lens> {
    Lens::from_json(text)
}

#[allow(clippy::too_many_arguments)]
fn options(
    method: &str,
    pixel_um: f64,
    size: usize,
    pupil_samples: usize,
    fft_grid: Option<usize>,
    aiming: &str,
    integrate: bool,
    exact: bool,
    fast: bool,
    accuracy: f64,
) -> PyResult<PsfOptions> {
    Ok(PsfOptions {
        method: method.parse::<Method>().map_err(to_py)?,
        pixel_mm: pixel_um * 1e-3,
        size,
        pupil_samples,
        fft_grid,
        aiming: aiming.parse::<Aiming>().map_err(to_py)?,
        huygens_exact: exact,
        integrate,
        fast,
        accuracy,
        progress: None,
    })
}

#[pyfunction]
fn validate_lens(py: Python<'_>, lens_json: &str) -> PyResult<()> {
    run(py, || parse_lens(lens_json).map(|_| ()))
}

#[pyfunction]
fn refractive_indices<'py>(
    py: Python<'py>,
    lens_json: &str,
    wavelength_nm: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let n = run(py, || parse_lens(lens_json)?.indices(wavelength_nm))?;
    Ok(n.into_pyarray(py))
}

#[pyfunction]
#[pyo3(signature = (lens_json, wavelength_nm=None))]
fn paraxial<'py>(py: Python<'py>, lens_json: &str, wavelength_nm: Option<f64>) -> PyResult<Bound<'py, PyDict>> {
    let p = run(py, || {
        let lens = parse_lens(lens_json)?;
        psf_engine::paraxial(&lens, wavelength_nm.unwrap_or(lens.primary_nm))
    })?;
    let d = PyDict::new(py);
    for (k, v) in [
        ("wavelength_nm", p.wavelength_nm),
        ("efl_mm", p.efl),
        ("bfl_mm", p.bfl),
        ("ffl_mm", p.ffl),
        ("f_number", p.f_number),
        ("epd_mm", p.epd),
        ("entrance_pupil_z_mm", p.entrance_pupil_z),
        ("xpd_mm", p.xpd),
        ("exit_pupil_z_mm", p.exit_pupil_z),
        ("stop_semi_diameter_mm", p.stop_semi_diameter),
        ("total_track_mm", p.total_track),
        ("image_z_mm", p.image_z),
        ("paraxial_image_height_mm", p.image_height),
        ("back_focus_shift_mm", p.back_focus_shift),
        ("object_to_pupil_mm", p.object_to_pupil),
    ] {
        d.set_item(k, v)?;
    }
    Ok(d)
}

/// Flat traced arrays to a dict of numpy arrays (the Vecs are handed over, not copied).
fn traced_dict<'py>(py: Python<'py>, t: psf_engine::Traced) -> PyResult<Bound<'py, PyDict>> {
    let n = t.opl.len();
    let d = PyDict::new(py);
    d.set_item("position", t.position.into_pyarray(py).reshape([n, 3])?)?;
    d.set_item("direction", t.direction.into_pyarray(py).reshape([n, 3])?)?;
    d.set_item("opl", t.opl.into_pyarray(py))?;
    d.set_item("status", t.status.into_pyarray(py))?;
    d.set_item("surface", t.surface.into_pyarray(py))?;
    d.set_item("origin", t.origin.into_pyarray(py).reshape([n, 3])?)?;
    Ok(d)
}

/// A float64 array as a slice, copying only when it is not contiguous.
fn contiguous<'a>(a: &'a PyReadonlyArray1<'_, f64>) -> std::borrow::Cow<'a, [f64]> {
    match a.as_slice() {
        Ok(s) => std::borrow::Cow::Borrowed(s),
        Err(_) => std::borrow::Cow::Owned(a.as_array().to_vec()),
    }
}

fn vec3s(a: &PyReadonlyArray2<f64>, name: &str) -> PyResult<Vec<f64>> {
    if a.shape().len() != 2 || a.shape()[1] != 3 {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "{name} must have shape (n, 3), got {:?}",
            a.shape()
        )));
    }
    Ok(match a.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => a.as_array().iter().copied().collect(),
    })
}

/// Single-thread seconds the engine's cost model predicts for one PSF (None for auto).
#[pyfunction]
#[pyo3(signature = (method, pixel_um, size, pupil_samples, fft_grid=None, n_surfaces=10))]
fn predicted_psf_seconds(
    method: &str,
    pixel_um: f64,
    size: usize,
    pupil_samples: usize,
    fft_grid: Option<usize>,
    n_surfaces: usize,
) -> PyResult<Option<f64>> {
    let o = options(
        method,
        pixel_um,
        size,
        pupil_samples,
        fft_grid,
        "paraxial",
        false,
        false,
        false,
        0.02,
    )?;
    Ok(psf_engine::psf::auto::predicted_seconds(&o, n_surfaces))
}

/// Memory available for new allocations (bytes), as the engine's size checks see it.
#[pyfunction]
fn available_memory() -> f64 {
    psf_engine::budget::available_bytes()
}

#[pyfunction]
fn trace<'py>(
    py: Python<'py>,
    lens_json: &str,
    origins: PyReadonlyArray2<f64>,
    directions: PyReadonlyArray2<f64>,
    wavelength_nm: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let o = vec3s(&origins, "origins")?;
    let d = vec3s(&directions, "directions")?;
    if o.len() != d.len() {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "origins ({}) and directions ({}) differ in length",
            o.len() / 3,
            d.len() / 3
        )));
    }
    let t = run(py, || {
        let lens = parse_lens(lens_json)?;
        let sys = psf_engine::System::new(&lens, wavelength_nm)?;
        Ok(sys.trace_soa(o.len() / 3, psf_engine::End::Image, |start, b| {
            for j in 0..b.len {
                let k = 3 * (start + j);
                b.set(j, [o[k], o[k + 1], o[k + 2]], [d[k], d[k + 1], d[k + 2]]);
            }
        }))
    })?;
    let dict = traced_dict(py, t)?;
    dict.del_item("origin")?;
    Ok(dict)
}

/// Pupil coordinates checked and made contiguous, then `f` run on the field's beam with
/// the GIL released; returns its result and the beam direction.
/// Unit directions of rays launched at points (flat x, y, z) on lines through a finite
/// object's point, travelling towards +z (a launch point may lie before or after it).
fn launch_directions(origins: &[f64], object: [f64; 3]) -> Vec<f64> {
    let mut out = Vec::with_capacity(origins.len());
    for o in origins.chunks_exact(3) {
        let s = if o[2] > object[2] { 1.0 } else { -1.0 };
        let d = [s * (o[0] - object[0]), s * (o[1] - object[1]), s * (o[2] - object[2])];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        out.extend(d.iter().map(|v| v / len));
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn with_beam<T: Send>(
    py: Python<'_>,
    lens_json: &str,
    field_deg: f64,
    px: &PyReadonlyArray1<'_, f64>,
    py_: &PyReadonlyArray1<'_, f64>,
    wavelength_nm: f64,
    aiming: &str,
    f: impl FnOnce(&psf_engine::Beam, &[f64], &[f64]) -> psf_engine::Result<T> + Send,
) -> PyResult<(T, [f64; 3], Option<[f64; 3]>)> {
    let (pxs, pys) = (contiguous(px), contiguous(py_));
    if pxs.len() != pys.len() {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "px ({}) and py ({}) differ in length",
            pxs.len(),
            pys.len()
        )));
    }
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    run(py, || {
        let lens = parse_lens(lens_json)?;
        let sys = psf_engine::System::new(&lens, wavelength_nm)?;
        let beam = psf_engine::Beam::new(&sys, field_deg, aiming)?;
        Ok((
            f(&beam, &pxs, &pys)?,
            beam.dir.to_array(),
            beam.object.map(|o| o.to_array()),
        ))
    })
}

#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, px, py_, wavelength_nm, aiming="paraxial"))]
fn trace_field<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    px: PyReadonlyArray1<'py, f64>,
    py_: PyReadonlyArray1<'py, f64>,
    wavelength_nm: f64,
    aiming: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let (t, dir, object) = with_beam(
        py,
        lens_json,
        field_deg,
        &px,
        &py_,
        wavelength_nm,
        aiming,
        |beam, x, y| Ok(beam.trace_pupil_soa(x, y)),
    )?;
    let n = t.opl.len();
    // A finite object's rays leave its object point: each towards it from its launch point.
    let per_ray = object.map(|o| launch_directions(&t.origin, o));
    let dict = traced_dict(py, t)?;
    match per_ray {
        Some(d) => dict.set_item("launch_direction", d.into_pyarray(py).reshape([n, 3])?)?,
        None => {
            // Every ray of a field leaves along the same direction: a read-only broadcast view.
            let one = dir.to_vec().into_pyarray(py);
            let launch = py.import("numpy")?.getattr("broadcast_to")?.call1((one, (n, 3)))?;
            dict.set_item("launch_direction", launch)?;
        }
    }
    Ok(dict)
}

#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, px, py_, wavelength_nm, aiming="paraxial"))]
fn trace_field_path<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    px: PyReadonlyArray1<'py, f64>,
    py_: PyReadonlyArray1<'py, f64>,
    wavelength_nm: f64,
    aiming: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let (p, dir, object) = with_beam(
        py,
        lens_json,
        field_deg,
        &px,
        &py_,
        wavelength_nm,
        aiming,
        |beam, x, y| beam.trace_path(x, y),
    )?;
    let (n, m) = (p.last.len(), p.points);
    let per_ray = object.map(|o| launch_directions(&p.image.origin, o));
    let dict = traced_dict(py, p.image)?;
    dict.set_item("path", p.position.into_pyarray(py).reshape([n, m, 3])?)?;
    dict.set_item("last", p.last.into_pyarray(py))?;
    match per_ray {
        Some(d) => dict.set_item("launch_direction", d.into_pyarray(py).reshape([n, 3])?)?,
        None => dict.set_item("launch_direction", dir.to_vec().into_pyarray(py))?,
    }
    Ok(dict)
}

/// OPD of pupil rays of one field at several wavelengths, piston and tilt removed
/// (psf_engine::wavefront): per-ray arrays handed to numpy without a copy.
#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, px, py_, weights, wavelengths_nm, wavelength_weights=None, aiming="paraxial", tilt="wavelength"))]
#[allow(clippy::too_many_arguments)]
fn wavefront<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    px: PyReadonlyArray1<'py, f64>,
    py_: PyReadonlyArray1<'py, f64>,
    weights: PyReadonlyArray1<'py, f64>,
    wavelengths_nm: Vec<f64>,
    wavelength_weights: Option<Vec<f64>>,
    aiming: &str,
    tilt: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    let tilt: psf_engine::wavefront::Tilt = tilt.parse().map_err(to_py)?;
    let ww = wavelength_weights.unwrap_or_else(|| vec![1.0; wavelengths_nm.len()]);
    let (xs, ys, ws) = (contiguous(&px), contiguous(&py_), contiguous(&weights));
    let nw = wavelengths_nm.len();
    let wf = run(py, || {
        psf_engine::wavefront::field_wavefront(
            &parse_lens(lens_json)?,
            field_deg,
            &wavelengths_nm,
            &ww,
            &xs,
            &ys,
            &ws,
            aiming,
            tilt,
        )
    })?;
    let n = wf.n_rays;
    let d = PyDict::new(py);
    d.set_item("opd_waves", wf.opd_waves.into_pyarray(py).reshape([nw, n])?)?;
    d.set_item("status", wf.status.into_pyarray(py).reshape([nw, n])?)?;
    d.set_item("rms_waves", wf.rms_waves.into_pyarray(py))?;
    let tilt_flat: Vec<f64> = wf.tilt_mm.iter().flatten().copied().collect();
    d.set_item("tilt_mm", tilt_flat.into_pyarray(py).reshape([nw, 2])?)?;
    d.set_item("chief_image_mm", wf.chief_image.to_array().to_vec())?;
    d.set_item("reference_radius_mm", wf.radius)?;
    Ok(d)
}

#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, wavelengths_nm, weights=None, rings=64, aiming="paraxial"))]
fn spot<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    wavelengths_nm: Vec<f64>,
    weights: Option<Vec<f64>>,
    rings: usize,
    aiming: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    let weights = weights.unwrap_or_else(|| vec![1.0; wavelengths_nm.len()]);
    if weights.len() != wavelengths_nm.len() || wavelengths_nm.is_empty() || rings == 0 {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "need >= 1 wavelength, one weight per wavelength and rings >= 1",
        ));
    }
    let r = run(py, move || {
        psf_engine::spot::spot_summary(
            &parse_lens(lens_json)?,
            field_deg,
            &wavelengths_nm,
            &weights,
            rings,
            aiming,
        )
    })?;
    json_to_py(py, &r).map(|o| o.cast_into::<PyDict>().unwrap())
}

#[pyfunction]
#[pyo3(signature = (lens_json, field_max_deg, wavelength_nm=None, aiming="paraxial"))]
fn field_fold<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_max_deg: f64,
    wavelength_nm: Option<f64>,
    aiming: &str,
) -> PyResult<Option<Bound<'py, PyDict>>> {
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    let f = run(py, move || {
        let lens = parse_lens(lens_json)?;
        psf_engine::spot::field_fold(&lens, field_max_deg, wavelength_nm.unwrap_or(lens.primary_nm), aiming)
    })?;
    f.map(|f| {
        let d = PyDict::new(py);
        d.set_item("field_deg", f.field_deg)?;
        d.set_item("px", f.px)?;
        d.set_item("py", f.py)?;
        d.set_item("step_mm", f.step_mm)?;
        Ok(d)
    })
    .transpose()
}

/// Largest radial height at each of the first `n_surfaces` surfaces of the pupil rays of
/// every field and wavelength that reach the image (psf_engine::aim::ray_footprint).
#[pyfunction]
#[pyo3(signature = (lens_json, n_surfaces, fields_deg, wavelengths_nm, px, py_, aiming="paraxial"))]
#[allow(clippy::too_many_arguments)]
fn ray_footprint<'py>(
    py: Python<'py>,
    lens_json: &str,
    n_surfaces: usize,
    fields_deg: Vec<f64>,
    wavelengths_nm: Vec<f64>,
    px: PyReadonlyArray1<'py, f64>,
    py_: PyReadonlyArray1<'py, f64>,
    aiming: &str,
) -> PyResult<Bound<'py, numpy::PyArray1<f64>>> {
    let (xs, ys) = (contiguous(&px), contiguous(&py_));
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    let h = run(py, || {
        let lens = parse_lens(lens_json)?;
        psf_engine::aim::ray_footprint(&lens, n_surfaces, &fields_deg, &wavelengths_nm, &xs, &ys, aiming)
    })?;
    Ok(h.into_pyarray(py))
}

/// The chief ray's status code (0-4) at each field and wavelength (fields outer), or the
/// message of the error where its beam cannot be launched.
#[pyfunction]
#[pyo3(signature = (lens_json, fields_deg, wavelengths_nm, aiming="paraxial"))]
fn chief_ray_status<'py>(
    py: Python<'py>,
    lens_json: &str,
    fields_deg: Vec<f64>,
    wavelengths_nm: Vec<f64>,
    aiming: &str,
) -> PyResult<Bound<'py, PyList>> {
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    let st = run(py, move || {
        let lens = parse_lens(lens_json)?;
        Ok(psf_engine::spot::chief_ray_status(
            &lens,
            &fields_deg,
            &wavelengths_nm,
            aiming,
        ))
    })?;
    let out = PyList::empty(py);
    for r in st {
        match r {
            Ok(code) => out.append(code)?,
            Err(e) => out.append(e.to_string())?,
        }
    }
    Ok(out)
}

#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, wavelength_nm, method="fft", pixel_um=1.0, size=64, pupil_samples=64, fft_grid=None, aiming="paraxial", integrate=false, exact=false, fast=false, accuracy=0.02, progress=None))]
#[allow(clippy::too_many_arguments)]
fn psf<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    wavelength_nm: f64,
    method: &str,
    pixel_um: f64,
    size: usize,
    pupil_samples: usize,
    fft_grid: Option<usize>,
    aiming: &str,
    integrate: bool,
    exact: bool,
    fast: bool,
    accuracy: f64,
    progress: Option<Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let mut o = options(
        method,
        pixel_um,
        size,
        pupil_samples,
        fft_grid,
        aiming,
        integrate,
        exact,
        fast,
        accuracy,
    )?;
    let p = match progress {
        None => run(py, || {
            psf_engine::psf::psf(&parse_lens(lens_json)?, field_deg, wavelength_nm, &o)
        })?,
        Some(callback) => {
            let lens = parse_lens(lens_json).map_err(to_py)?;
            watched(py, &mut o, &callback, move |o| {
                psf_engine::psf::psf(&lens, field_deg, wavelength_nm, o)
            })?
        }
    };
    let arr = p.data.into_pyarray(py).reshape([size, size])?.into_any();
    Ok((arr, json_to_py(py, &p.diagnostics.to_json())?))
}

#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, channels, method="fft", pixel_um=1.0, size=64, pupil_samples=64, aiming="paraxial", integrate=false, fast=true, accuracy=0.02))]
#[allow(clippy::too_many_arguments)]
fn psf_rgb<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    channels: Vec<Vec<(f64, f64)>>,
    method: &str,
    pixel_um: f64,
    size: usize,
    pupil_samples: usize,
    aiming: &str,
    integrate: bool,
    fast: bool,
    accuracy: f64,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let o = options(
        method,
        pixel_um,
        size,
        pupil_samples,
        None,
        aiming,
        integrate,
        false,
        fast,
        accuracy,
    )?;
    let nc = channels.len();
    let r = run(py, || {
        psf_engine::rgb::psf_rgb(&parse_lens(lens_json)?, field_deg, &channels, &o)
    })?;
    let arr = r.data.into_pyarray(py).reshape([nc, size, size])?.into_any();
    let ri = r.relative_illumination.into_pyarray(py).into_any();
    let diags = serde_json::Value::Array(r.diagnostics.iter().map(|d| d.to_json()).collect());
    Ok((arr, ri, json_to_py(py, &serde_json::json!({"per_wavelength": diags}))?))
}

/// A caller's output array must be C-contiguous with this shape.
fn check_out(name: &str, a: Option<&numpy::PyReadwriteArrayDyn<'_, f32>>, shape: &[usize]) -> PyResult<()> {
    if let Some(a) = a {
        if a.shape() != shape || !a.is_c_contiguous() {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "{name}: need a C-contiguous float32 array of shape {shape:?}, got shape {:?}{}",
                a.shape(),
                if a.is_c_contiguous() { "" } else { " (not C-contiguous)" }
            )));
        }
    }
    Ok(())
}

fn out_slice<'a>(
    name: &str,
    a: Option<&'a mut numpy::PyReadwriteArrayDyn<'_, f32>>,
) -> PyResult<Option<&'a mut [f32]>> {
    a.map(|a| {
        a.as_slice_mut()
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("{name}: {e}")))
    })
    .transpose()
}

/// CRC-32 (IEEE, as zlib's) of a byte array, continuing from `crc`; GIL released.
#[pyfunction]
#[pyo3(signature = (data, crc=0))]
fn crc32(py: Python<'_>, data: numpy::PyReadonlyArrayDyn<'_, u8>, crc: u32) -> PyResult<u32> {
    let bytes = data
        .as_slice()
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("crc32: {e}")))?;
    Ok(py.detach(|| {
        let mut h = crc32fast::Hasher::new_with_initial(crc);
        h.update(bytes);
        h.finalize()
    }))
}

#[pyfunction]
#[pyo3(signature = (lens_jsons, fields_deg, channels, method="fft", pixel_um=1.0, size=64, pupil_samples=64, aiming="paraxial", integrate=false, fast=true, out=None, sensor=None, sensor_out=None, accuracy=0.02))]
#[allow(clippy::too_many_arguments)]
fn psf_batch<'py>(
    py: Python<'py>,
    lens_jsons: Vec<String>,
    fields_deg: Vec<f64>,
    channels: Vec<Vec<(f64, f64)>>,
    method: &str,
    pixel_um: f64,
    size: usize,
    pupil_samples: usize,
    aiming: &str,
    integrate: bool,
    fast: bool,
    out: Option<numpy::PyReadwriteArrayDyn<'py, f32>>,
    sensor: Option<(f64, usize)>,
    sensor_out: Option<numpy::PyReadwriteArrayDyn<'py, f32>>,
    accuracy: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let o = options(
        method,
        pixel_um,
        size,
        pupil_samples,
        None,
        aiming,
        integrate,
        false,
        fast,
        accuracy,
    )?;
    let (nd, nf, nc) = (lens_jsons.len(), fields_deg.len(), channels.len());
    let shape = [nd, nf, nc, size, size];
    let binning = match sensor {
        Some((pitch_um, m)) => {
            Some(psf_engine::rgb::SensorBinning::new(size, pixel_um * 1e-3, m, pitch_um * 1e-3).map_err(to_py)?)
        }
        None if sensor_out.is_some() => {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "sensor_out without sensor=(pitch_um, size)",
            ))
        }
        None => None,
    };
    let sshape = binning.as_ref().map(|b| [nd, nf, nc, b.size(), b.size()]);
    let mut out = out;
    let mut sensor_out = sensor_out;
    check_out("out", out.as_ref(), &shape)?;
    if let Some(ss) = &sshape {
        check_out("sensor_out", sensor_out.as_ref(), ss)?;
    }
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let own_sensor = binning.as_ref().filter(|_| sensor_out.is_none()).map(|b| b.size());
    psf_engine::rgb::batch_memory(nd, nf, nc, &o, threads, out.is_none(), own_sensor)
        .check("psf_batch")
        .map_err(to_py)?;
    let out_array: Option<Bound<'py, PyAny>> = out.as_ref().map(|a| a.as_any().clone());
    let sensor_array: Option<Bound<'py, PyAny>> = sensor_out.as_ref().map(|a| a.as_any().clone());
    let slice = out_slice("out", out.as_mut())?;
    let sensor_slice = out_slice("sensor_out", sensor_out.as_mut())?;
    let (batch, owned, owned_sensor, parse_errors) = run(py, move || {
        // Designs that do not parse are failures of that design, not of the call.
        let parsed: Vec<psf_engine::Result<Lens>> = lens_jsons.iter().map(|t| parse_lens(t)).collect();
        let placeholder = parsed.iter().find_map(|r| r.as_ref().ok().cloned());
        let lenses: Vec<Lens> = match &placeholder {
            Some(p) => parsed
                .iter()
                .map(|r| r.as_ref().ok().cloned().unwrap_or_else(|| p.clone()))
                .collect(),
            None => vec![],
        };
        let errs: Vec<Option<String>> = parsed.iter().map(|r| r.as_ref().err().map(|e| e.to_string())).collect();
        let per = nf * nc * size * size;
        // the caller's array, or one of our own returned as a new array
        let mut owned: Option<Vec<f32>> = None;
        let buf: &mut [f32] = match slice {
            Some(b) => b,
            None => owned.insert(psf_engine::rgb::output_buffer(nd * per)),
        };
        let mut owned_sensor: Option<Vec<f32>> = None;
        let mut sensor: Option<(&psf_engine::rgb::SensorBinning, &mut [f32])> = match (&binning, sensor_slice) {
            (Some(b), Some(sb)) => Some((b, sb)),
            (Some(b), None) => Some((b, owned_sensor.insert(vec![0.0; nd * nf * nc * b.size() * b.size()]))),
            _ => None,
        };
        let b = if lenses.is_empty() {
            psf_engine::rgb::Batch {
                psf: vec![],
                relative_illumination: vec![0.0; nd * nf * nc],
                energy_in_window: vec![0.0; nd * nf * nc],
                warnings: vec![vec![]; nd],
                errors: vec![None; nd],
                methods: vec![String::new(); nd * nf * channels.iter().map(|c| c.len()).sum::<usize>()],
            }
        } else {
            psf_engine::rgb::psf_batch_into(
                &lenses,
                &fields_deg,
                &channels,
                &o,
                buf,
                sensor.as_mut().map(|(b, s)| (*b, &mut **s)),
            )?
        };
        // A design that does not parse was traced as a placeholder (or not at all): zeros.
        psf_engine::rgb::zero_failed(buf, &errs);
        if let Some((_, sb)) = sensor {
            psf_engine::rgb::zero_failed(sb, &errs);
        }
        Ok((b, owned, owned_sensor, errs))
    })?;
    let mut errors = batch.errors;
    let mut ri = batch.relative_illumination;
    let mut energy = batch.energy_in_window;
    let mut warnings = batch.warnings;
    psf_engine::rgb::zero_failed(&mut ri, &parse_errors);
    psf_engine::rgb::zero_failed(&mut energy, &parse_errors);
    for (i, e) in parse_errors.into_iter().enumerate() {
        if let Some(msg) = e {
            errors[i] = Some(msg);
            warnings[i].clear();
        }
    }
    let d = PyDict::new(py);
    match (owned, out_array) {
        (Some(v), _) => d.set_item("psf", v.into_pyarray(py).reshape(shape)?)?,
        (None, Some(a)) => d.set_item("psf", a)?,
        (None, None) => unreachable!("either the engine's buffer or the caller's"),
    }
    if let Some(ss) = sshape {
        match (owned_sensor, sensor_array) {
            (Some(v), _) => d.set_item("psf_sensor", v.into_pyarray(py).reshape(ss)?)?,
            (None, Some(a)) => d.set_item("psf_sensor", a)?,
            (None, None) => unreachable!("either the engine's sensor buffer or the caller's"),
        }
    }
    d.set_item("relative_illumination", ri.into_pyarray(py).reshape([nd, nf, nc])?)?;
    d.set_item("energy_in_window", energy.into_pyarray(py).reshape([nd, nf, nc])?)?;
    d.set_item("warnings", warnings)?;
    d.set_item("methods", batch.methods)?;
    d.set_item(
        "ok",
        errors.iter().map(|e| e.is_none()).collect::<Vec<_>>().into_pyarray(py),
    )?;
    d.set_item("errors", errors)?;
    Ok(d)
}

/// method = auto's probe and its candidates (predicted error and cost, cheapest first), for
/// calibration and inspection.
#[pyfunction]
#[pyo3(signature = (lens_json, field_deg, wavelength_nm, pixel_um=1.0, size=64, aiming="paraxial", integrate=false))]
#[allow(clippy::too_many_arguments)]
fn auto_candidates<'py>(
    py: Python<'py>,
    lens_json: &str,
    field_deg: f64,
    wavelength_nm: f64,
    pixel_um: f64,
    size: usize,
    aiming: &str,
    integrate: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let o = options("auto", pixel_um, size, 64, None, aiming, integrate, false, false, 0.02)?;
    let v = run(py, || {
        let lens = parse_lens(lens_json)?;
        let pr = psf_engine::psf::auto::probe(&lens, field_deg, wavelength_nm, o.aiming, o.size as f64 * o.pixel_mm)?;
        let c = psf_engine::psf::auto::candidates(&pr, &o, lens.surfaces.len());
        Ok(serde_json::json!({
            "probe": psf_engine::psf::auto::probe_json(&pr),
            "candidates": c.iter().map(psf_engine::psf::auto::candidate_json).collect::<Vec<_>>(),
        }))
    })?;
    json_to_py(py, &v)
}

#[pyfunction]
#[pyo3(signature = (lens_jsons, fields_deg, wavelengths, rings=8, aiming="paraxial"))]
fn best_focus_batch<'py>(
    py: Python<'py>,
    lens_jsons: Vec<String>,
    fields_deg: Vec<f64>,
    wavelengths: Vec<(f64, f64)>,
    rings: usize,
    aiming: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let aiming: Aiming = aiming.parse().map_err(to_py)?;
    let results: Vec<Result<f64, String>> = run(py, || {
        // a design that does not parse is that design's failure, not the call's
        let parsed: Vec<psf_engine::Result<Lens>> = lens_jsons.iter().map(|t| parse_lens(t)).collect();
        let good: Vec<Lens> = parsed.iter().filter_map(|r| r.as_ref().ok().cloned()).collect();
        let mut shifts =
            psf_engine::focus::best_focus_each(&good, &fields_deg, &wavelengths, rings, aiming).into_iter();
        Ok(parsed
            .into_iter()
            .map(|r| match r {
                Ok(_) => shifts
                    .next()
                    .expect("one result per parsed design")
                    .map_err(|e| e.to_string()),
                Err(e) => Err(e.to_string()),
            })
            .collect())
    })?;
    let shift: Vec<f64> = results.iter().map(|r| *r.as_ref().unwrap_or(&0.0)).collect();
    let errors: Vec<Option<String>> = results.into_iter().map(|r| r.err()).collect();
    let d = PyDict::new(py);
    d.set_item("shift_mm", shift.into_pyarray(py))?;
    d.set_item(
        "ok",
        errors.iter().map(|e| e.is_none()).collect::<Vec<_>>().into_pyarray(py),
    )?;
    d.set_item("errors", errors)?;
    Ok(d)
}

/// The best-focus rule as Python passes it: (fields_deg, (nm, weight) pairs, rings).
type FocusArg = (Vec<f64>, Vec<(f64, f64)>, usize);

/// A lens parameter from its name: (kind, surface (0-based), aspheric term index).
fn parse_param(kind: &str, surface: usize, term: usize) -> PyResult<psf_engine::tangent::Param> {
    use psf_engine::tangent::Param;
    Ok(match kind {
        "curvature" => Param::Curvature(surface),
        "radius" => Param::Radius(surface),
        "conic" => Param::Conic(surface),
        "aspheric" => Param::Aspheric(surface, term),
        "thickness" => Param::Thickness(surface),
        "f_number" => Param::FNumber,
        "epd" => Param::Epd,
        _ => {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "parameter kind {kind:?}: use curvature, radius, conic, aspheric, thickness, f_number or epd"
            )))
        }
    })
}

/// The one-pass gradient of one design's PSF set (psf_engine::gradient::psf_set_vjp).
#[pyfunction]
#[pyo3(signature = (lens_json, fields_deg, channels, params, g_psf, g_ri, method="auto", pixel_um=1.0, size=64, pupil_samples=64, aiming="paraxial", accuracy=0.02, sensor=None, focus=None))]
#[allow(clippy::too_many_arguments)]
fn psf_set_vjp<'py>(
    py: Python<'py>,
    lens_json: &str,
    fields_deg: Vec<f64>,
    channels: Vec<Vec<(f64, f64)>>,
    params: Vec<(String, usize, usize)>,
    g_psf: numpy::PyReadonlyArrayDyn<'py, f64>,
    g_ri: numpy::PyReadonlyArrayDyn<'py, f64>,
    method: &str,
    pixel_um: f64,
    size: usize,
    pupil_samples: usize,
    aiming: &str,
    accuracy: f64,
    sensor: Option<(f64, usize)>,
    focus: Option<FocusArg>,
) -> PyResult<Bound<'py, PyDict>> {
    let o = options(
        method,
        pixel_um,
        size,
        pupil_samples,
        None,
        aiming,
        false,
        false,
        true,
        accuracy,
    )?;
    let params = params
        .iter()
        .map(|(k, s, t)| parse_param(k, *s, *t))
        .collect::<PyResult<Vec<_>>>()?;
    let binning = match sensor {
        Some((pitch_um, m)) => {
            Some(psf_engine::rgb::SensorBinning::new(size, pixel_um * 1e-3, m, pitch_um * 1e-3).map_err(to_py)?)
        }
        None => None,
    };
    let focus = focus.map(|(fields, wavelengths, rings)| psf_engine::gradient::FocusRule {
        fields,
        wavelengths,
        rings,
    });
    fn contiguous(name: &str, a: &numpy::PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<f64>> {
        a.as_slice()
            .map(|s| s.to_vec())
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("{name}: {e}")))
    }
    let (gp, gr) = (contiguous("g_psf", &g_psf)?, contiguous("g_ri", &g_ri)?);
    let (nf, nc) = (fields_deg.len(), channels.len());
    let r = run(py, || {
        psf_engine::gradient::psf_set_vjp(
            &parse_lens(lens_json)?,
            &fields_deg,
            &channels,
            &o,
            binning.as_ref(),
            &params,
            focus.as_ref(),
            &gp,
            &gr,
        )
    })?;
    let d = PyDict::new(py);
    d.set_item("fallback", r.fallback.clone())?;
    if r.fallback.is_none() {
        d.set_item("grad", r.grad.into_pyarray(py))?;
        d.set_item("psf", r.psf.into_pyarray(py).reshape([nf, nc, size, size])?)?;
        d.set_item(
            "relative_illumination",
            r.relative_illumination.into_pyarray(py).reshape([nf, nc])?,
        )?;
    } else {
        d.set_item("grad", py.None())?;
        d.set_item("psf", py.None())?;
        d.set_item("relative_illumination", py.None())?;
    }
    Ok(d)
}

#[pymodule]
fn _engine(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    let simd = match psf_engine::kernel::simd_level() {
        psf_engine::kernel::Simd::Avx512 => "avx512",
        psf_engine::kernel::Simd::Avx2 => "avx2",
        psf_engine::kernel::Simd::Baseline => "baseline",
    };
    m.add("simd", simd)?;
    m.add("EngineError", py.get_type::<EngineError>())?;
    m.add("LensError", py.get_type::<LensError>())?;
    m.add("MaterialError", py.get_type::<MaterialError>())?;
    m.add("TraceError", py.get_type::<TraceError>())?;
    m.add("PsfError", py.get_type::<PsfError>())?;
    m.add_function(wrap_pyfunction!(available_memory, m)?)?;
    m.add_function(wrap_pyfunction!(predicted_psf_seconds, m)?)?;
    m.add_function(wrap_pyfunction!(validate_lens, m)?)?;
    m.add_function(wrap_pyfunction!(refractive_indices, m)?)?;
    m.add_function(wrap_pyfunction!(paraxial, m)?)?;
    m.add_function(wrap_pyfunction!(trace, m)?)?;
    m.add_function(wrap_pyfunction!(trace_field, m)?)?;
    m.add_function(wrap_pyfunction!(trace_field_path, m)?)?;
    m.add_function(wrap_pyfunction!(spot, m)?)?;
    m.add_function(wrap_pyfunction!(field_fold, m)?)?;
    m.add_function(wrap_pyfunction!(chief_ray_status, m)?)?;
    m.add_function(wrap_pyfunction!(ray_footprint, m)?)?;
    m.add_function(wrap_pyfunction!(wavefront, m)?)?;
    m.add_function(wrap_pyfunction!(best_focus_batch, m)?)?;
    m.add_function(wrap_pyfunction!(psf_set_vjp, m)?)?;
    m.add_function(wrap_pyfunction!(psf, m)?)?;
    m.add_function(wrap_pyfunction!(psf_rgb, m)?)?;
    m.add_function(wrap_pyfunction!(psf_batch, m)?)?;
    m.add_function(wrap_pyfunction!(crc32, m)?)?;
    m.add_function(wrap_pyfunction!(auto_candidates, m)?)?;
    Ok(())
}
