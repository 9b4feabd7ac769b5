//! The lens model: a sequential, rotationally symmetric system of standard (conic) and
//! even-asphere surfaces, the object at infinity or at a finite distance in front of the
//! first surface, image plane after the last thickness.
//! `Lens::from_json` reads the resolved JSON prescription (docs/lens-format.md) and
//! checks it, naming the surface (1-based) and parameter of every problem.

use crate::error::{EngineError, Result};
use crate::material::Material;
use serde_json::{Map, Value};

// A surface's data lives with its geometry (surface.rs); callers name it from here too.
pub use crate::surface::{Surface, MAX_ASPHERE_TERMS, ODD_TERMS};

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Aperture {
    /// Entrance pupil diameter (mm).
    Epd(f64),
    /// Image-space paraxial f-number (EFL / EPD).
    FNumber(f64),
    /// Object-space numerical aperture n sin(u) of the axial marginal ray (finite objects):
    /// the EPD whose paraxially aimed marginal ray leaves the axial object point at u.
    ObjectNA(f64),
}

#[derive(Debug, Clone, PartialEq)]
pub struct Lens {
    pub name: String,
    pub surfaces: Vec<Surface>,
    /// Material after surface i is `media[i + 1]`; `media[0]` is object space (air).
    pub media: Vec<Material>,
    /// Index into `surfaces` of the aperture stop.
    pub stop: usize,
    pub aperture: Aperture,
    pub fields_deg: Vec<f64>,
    pub wavelengths_nm: Vec<f64>,
    pub weights: Vec<f64>,
    pub primary_nm: f64,
    pub image_z: f64,
    pub image_semi_diameter: Option<f64>,
    /// Curvature of the image surface (1/mm; 0 for a flat sensor). Ray traces end on the
    /// sphere; wave-optics analyses of one field use `image::flat_at_field`.
    pub image_curvature: f64,
    /// Object plane to first vertex (mm, >= 0); infinite for an object at infinity.
    pub object_distance: f64,
}

/// Largest length (mm) a thickness, semi-diameter, EPD or object distance may have, and the
/// largest radius (a huge radius is a way to write a plane): perturbing a length near the
/// float maximum overflows; these leave any design room.
pub const MAX_LENGTH_MM: f64 = 1e12;
pub const MAX_RADIUS_MM: f64 = 1e30;

/// `v` of at most [`MAX_LENGTH_MM`] ([`MAX_RADIUS_MM`] for a radius); infinite values are the
/// caller's to allow or refuse.
fn check_length(v: f64, ctx: &str, key: &str) -> Result<()> {
    let max = if key == "radius" { MAX_RADIUS_MM } else { MAX_LENGTH_MM };
    if v.is_finite() && v.abs() > max {
        return lens_err(format!("{ctx}: \"{key}\" {v:e} mm is beyond {max:e} mm"));
    }
    Ok(())
}

fn lens_err<T>(msg: String) -> Result<T> {
    Err(EngineError::Lens(msg))
}

fn get_f64(obj: &Map<String, Value>, key: &str, ctx: &str) -> Result<Option<f64>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Number(n)) => {
            let v = n.as_f64().unwrap_or(f64::NAN);
            if v.is_finite() {
                Ok(Some(v))
            } else {
                lens_err(format!("{ctx}: \"{key}\" is not a finite number"))
            }
        }
        Some(Value::String(s)) if matches!(s.to_ascii_lowercase().as_str(), "inf" | "infinity") => {
            Ok(Some(f64::INFINITY))
        }
        Some(v) => lens_err(format!("{ctx}: \"{key}\" must be a number, got {v}")),
    }
}

fn get_f64_list(obj: &Map<String, Value>, key: &str, ctx: &str) -> Result<Option<Vec<f64>>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Array(a)) => a
            .iter()
            .enumerate()
            .map(|(i, v)| match v.as_f64() {
                Some(x) if x.is_finite() => Ok(x),
                _ => lens_err(format!("{ctx}: \"{key}\"[{i}] must be a finite number, got {v}")),
            })
            .collect::<Result<Vec<_>>>()
            .map(Some),
        Some(v) => lens_err(format!("{ctx}: \"{key}\" must be a list of numbers, got {v}")),
    }
}

fn parse_material(v: Option<&Value>, ctx: &str) -> Result<Material> {
    let m = match v {
        None | Some(Value::Null) => Material::Air,
        Some(Value::String(s)) if s.eq_ignore_ascii_case("air") || s.eq_ignore_ascii_case("vacuum") => Material::Air,
        Some(Value::String(s)) => {
            return lens_err(format!(
                "{ctx}: material \"{s}\" is a catalog name; the engine takes resolved materials (load the lens through optix_e2e.Lens)"
            ))
        }
        Some(Value::Object(o)) => {
            let name = o.get("name").and_then(Value::as_str).unwrap_or("").to_string();
            if let Some(n) = get_f64(o, "n", ctx)? {
                Material::Constant(n)
            } else if o.contains_key("nd") || o.contains_key("vd") {
                let nd = get_f64(o, "nd", ctx)?.ok_or_else(|| EngineError::Lens(format!("{ctx}: model glass needs \"nd\"")))?;
                let vd = get_f64(o, "vd", ctx)?.ok_or_else(|| EngineError::Lens(format!("{ctx}: model glass needs \"vd\"")))?;
                Material::Model { nd, vd }
            } else if let Some(kind) = o.get("formula") {
                let kind = kind
                    .as_u64()
                    .filter(|k| (1..=9).contains(k))
                    .ok_or_else(|| EngineError::Lens(format!("{ctx}: material \"formula\" must be an integer 1-9, got {kind}")))?;
                let coefficients = get_f64_list(o, "coefficients", ctx)?
                    .ok_or_else(|| EngineError::Lens(format!("{ctx}: material formula needs \"coefficients\"")))?;
                let range_um = match get_f64_list(o, "range_um", ctx)? {
                    None => None,
                    Some(r) if r.len() == 2 => Some((r[0], r[1])),
                    Some(_) => return lens_err(format!("{ctx}: material \"range_um\" must be [lo, hi]")),
                };
                Material::Formula { kind: kind as u8, coefficients, range_um, name: if name.is_empty() { format!("formula {kind}") } else { name } }
            } else if let Some(t) = o.get("tabulated") {
                let rows = t.as_array().ok_or_else(|| EngineError::Lens(format!("{ctx}: \"tabulated\" must be a list of [wl_um, n]")))?;
                let mut wl = Vec::with_capacity(rows.len());
                let mut n = Vec::with_capacity(rows.len());
                for (i, r) in rows.iter().enumerate() {
                    match r.as_array().map(|a| (a.first().and_then(Value::as_f64), a.get(1).and_then(Value::as_f64))) {
                        Some((Some(w), Some(x))) => {
                            wl.push(w);
                            n.push(x);
                        }
                        _ => return lens_err(format!("{ctx}: \"tabulated\"[{i}] must be [wl_um, n]")),
                    }
                }
                Material::Tabulated { wavelength_um: wl, n, name: if name.is_empty() { "tabulated".into() } else { name } }
            } else if o.contains_key("glass") {
                return lens_err(format!(
                    "{ctx}: catalog glass {} must be resolved before it reaches the engine (load the lens through optix_e2e.Lens)",
                    o["glass"]
                ));
            } else {
                return lens_err(format!("{ctx}: material needs one of \"n\", \"nd\"/\"vd\", \"formula\" or \"tabulated\""));
            }
        }
        Some(v) => return lens_err(format!("{ctx}: material must be \"air\" or an object, got {v}")),
    };
    m.validate().map_err(|e| EngineError::Lens(format!("{ctx}: {e}")))?;
    Ok(m)
}

impl Lens {
    /// Parse and validate a resolved JSON prescription.
    pub fn from_json(text: &str) -> Result<Lens> {
        let v: Value = serde_json::from_str(text)
            .map_err(|e| EngineError::Lens(format!("invalid JSON at line {} column {}: {e}", e.line(), e.column())))?;
        let root = v
            .as_object()
            .ok_or_else(|| EngineError::Lens("prescription must be a JSON object".into()))?;
        if let Some(u) = root.get("units").and_then(Value::as_str) {
            if u != "mm" {
                return lens_err(format!("units \"{u}\" not supported: only \"mm\""));
            }
        }
        let name = root.get("name").and_then(Value::as_str).unwrap_or("lens").to_string();
        let ap = root.get("aperture").and_then(Value::as_object).ok_or_else(|| {
            EngineError::Lens("missing \"aperture\": {\"type\": \"epd\"|\"fno\", \"value\": ...}".into())
        })?;
        let ap_value =
            get_f64(ap, "value", "aperture")?.ok_or_else(|| EngineError::Lens("aperture: missing \"value\"".into()))?;
        if !(ap_value.is_finite() && ap_value > 0.0) {
            return lens_err(format!("aperture: \"value\" must be positive, got {ap_value}"));
        }
        check_length(ap_value, "aperture", "value")?;
        let aperture = match ap
            .get("type")
            .and_then(Value::as_str)
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("epd") => Aperture::Epd(ap_value),
            Some("fno") | Some("f_number") => Aperture::FNumber(ap_value),
            Some("object_na") => Aperture::ObjectNA(ap_value),
            other => {
                return lens_err(format!(
                    "aperture: \"type\" must be \"epd\", \"fno\" or \"object_na\", got {other:?}"
                ))
            }
        };
        let object_distance = get_f64(root, "object_distance", "lens")?.unwrap_or(f64::INFINITY);
        check_length(object_distance, "lens", "object_distance")?;
        if !(object_distance >= 0.0) {
            return lens_err(format!(
                "object_distance = {object_distance} must be >= 0 mm (object plane to the first surface) or \"inf\""
            ));
        }
        if let Aperture::ObjectNA(na) = aperture {
            if object_distance.is_infinite() {
                return lens_err("aperture: \"object_na\" needs a finite \"object_distance\" (an object at infinity has no object-space NA)".into());
            }
            if na >= 1.0 {
                return lens_err(format!(
                    "aperture: object-space NA {na} must be below 1 (the object is in air)"
                ));
            }
        }
        let fields_deg = get_f64_list(root, "fields_deg", "lens")?.unwrap_or_else(|| vec![0.0]);
        for (i, f) in fields_deg.iter().enumerate() {
            if !(0.0..90.0).contains(&f.abs()) {
                return lens_err(format!("fields_deg[{i}] = {f} must be within (-90, 90) degrees"));
            }
        }
        let wavelengths_nm = get_f64_list(root, "wavelengths_nm", "lens")?.unwrap_or_else(|| vec![587.5618]);
        if wavelengths_nm.is_empty() || wavelengths_nm.iter().any(|w| !(*w > 0.0)) {
            return lens_err("wavelengths_nm must be a non-empty list of positive numbers".into());
        }
        let weights =
            get_f64_list(root, "wavelength_weights", "lens")?.unwrap_or_else(|| vec![1.0; wavelengths_nm.len()]);
        if weights.len() != wavelengths_nm.len()
            || weights.iter().any(|w| *w < 0.0)
            || weights.iter().sum::<f64>() <= 0.0
        {
            return lens_err("wavelength_weights must match wavelengths_nm in length, be >= 0 and not all zero".into());
        }
        let primary_nm =
            get_f64(root, "primary_wavelength_nm", "lens")?.unwrap_or(wavelengths_nm[wavelengths_nm.len() / 2]);
        if !(primary_nm > 0.0 && primary_nm.is_finite()) {
            return lens_err(format!("primary_wavelength_nm = {primary_nm} must be positive"));
        }

        let list = root
            .get("surfaces")
            .and_then(Value::as_array)
            .ok_or_else(|| EngineError::Lens("missing \"surfaces\" list".into()))?;
        if list.is_empty() {
            return lens_err("\"surfaces\" is empty".into());
        }
        let mut surfaces = Vec::with_capacity(list.len());
        let mut media = vec![Material::Air];
        let mut stop = None;
        let mut z = 0.0;
        for (i, sv) in list.iter().enumerate() {
            let ctx = format!("surface {}", i + 1);
            let s = sv
                .as_object()
                .ok_or_else(|| EngineError::Lens(format!("{ctx}: must be an object")))?;
            let radius = get_f64(s, "radius", &ctx)?;
            if let Some(r) = radius {
                check_length(r, &ctx, "radius")?;
            }
            let curv = get_f64(s, "curvature", &ctx)?;
            let curvature = match (radius, curv) {
                (Some(_), Some(_)) => return lens_err(format!("{ctx}: give \"radius\" or \"curvature\", not both")),
                (Some(r), None) if r.is_infinite() => 0.0,
                (Some(0.0), None) => {
                    return lens_err(format!(
                        "{ctx}: \"radius\" 0 is not a surface (use \"inf\" for a plane)"
                    ))
                }
                (Some(r), None) => 1.0 / r,
                (None, Some(c)) if c.is_finite() => c,
                (None, Some(_)) => return lens_err(format!("{ctx}: \"curvature\" must be finite")),
                (None, None) => 0.0,
            };
            let thickness = get_f64(s, "thickness", &ctx)?
                .ok_or_else(|| EngineError::Lens(format!("{ctx}: missing \"thickness\"")))?;
            check_length(thickness, &ctx, "thickness")?;
            if !thickness.is_finite() {
                return lens_err(format!(
                    "{ctx}: \"thickness\" must be finite (the object distance is \"object_distance\")"
                ));
            }
            let conic = get_f64(s, "conic", &ctx)?.unwrap_or(0.0);
            if !conic.is_finite() {
                return lens_err(format!("{ctx}: \"conic\" must be finite"));
            }
            let mut aspheric = [0.0; MAX_ASPHERE_TERMS];
            let mut odd = [0.0; ODD_TERMS];
            match s.get("aspheric") {
                None | Some(Value::Null) => {}
                Some(Value::Object(a)) => {
                    for (k, v) in a {
                        let order: Option<usize> = k.strip_prefix('a').and_then(|o| o.parse().ok());
                        let slot = match order {
                            Some(o) if (2..=2 * MAX_ASPHERE_TERMS).contains(&o) && o % 2 == 0 => {
                                &mut aspheric[o / 2 - 1]
                            }
                            Some(o) if o % 2 == 1 && o < 2 * ODD_TERMS => &mut odd[o / 2],
                            _ => {
                                return lens_err(format!(
                                    "{ctx}: aspheric term \"{k}\" unknown (use a1, a2, ..., a7, a8, a10, ..., a20)"
                                ))
                            }
                        };
                        *slot = v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                            EngineError::Lens(format!("{ctx}: aspheric \"{k}\" must be a finite number"))
                        })?;
                    }
                }
                Some(v) => {
                    return lens_err(format!(
                        "{ctx}: \"aspheric\" must be an object like {{\"a4\": 1e-5}}, got {v}"
                    ))
                }
            }
            let semi_diameter = get_f64(s, "semi_diameter", &ctx)?;
            if let Some(sd) = semi_diameter {
                check_length(sd, &ctx, "semi_diameter")?;
            }
            if let Some(sd) = semi_diameter {
                if !(sd > 0.0 && sd.is_finite()) {
                    return lens_err(format!("{ctx}: \"semi_diameter\" must be positive, got {sd}"));
                }
                // A clear aperture beyond where the conic surface exists cannot be made.
                let arg = 1.0 - (1.0 + conic) * curvature * curvature * sd * sd;
                if arg < -crate::surface::RIM_TOLERANCE {
                    return lens_err(format!(
                        "{ctx}: \"semi_diameter\" {sd} exceeds the surface's extent (the conic sag is undefined there)"
                    ));
                }
            }
            if s.get("stop").and_then(Value::as_bool).unwrap_or(false) {
                if let Some(prev) = stop {
                    return lens_err(format!("{ctx}: second stop (surface {} is already the stop)", prev + 1));
                }
                stop = Some(i);
            }
            media.push(parse_material(s.get("material"), &ctx)?);
            let name = s.get("name").and_then(Value::as_str).unwrap_or("").to_string();
            surfaces.push(Surface {
                curvature,
                conic,
                aspheric,
                odd,
                thickness,
                z,
                semi_diameter,
                name,
            });
            z += thickness;
        }
        let stop = stop.ok_or_else(|| EngineError::Lens("no surface has \"stop\": true".into()))?;
        let image = root.get("image").and_then(Value::as_object);
        let image_semi_diameter = image
            .map(|o| get_f64(o, "semi_diameter", "image"))
            .transpose()?
            .flatten();
        for (key, v) in [
            ("semi_diameter", image_semi_diameter),
            (
                "radius",
                image.map(|o| get_f64(o, "radius", "image")).transpose()?.flatten(),
            ),
        ] {
            if let Some(v) = v {
                check_length(v, "image", key)?;
            }
        }
        if let Some(sd) = image_semi_diameter {
            if !(sd > 0.0 && sd.is_finite()) {
                return lens_err(format!("image: \"semi_diameter\" must be positive, got {sd}"));
            }
        }
        let image_curvature = match image.map(|o| get_f64(o, "radius", "image")).transpose()?.flatten() {
            None => 0.0,
            Some(r) if r.is_infinite() => 0.0,
            Some(0.0) => return lens_err("image: \"radius\" 0 is not a surface (use \"inf\" for a flat image)".into()),
            Some(r) => 1.0 / r,
        };
        if let Some(sd) = image_semi_diameter {
            if image_curvature * image_curvature * sd * sd >= 1.0 {
                return lens_err(format!(
                    "image: \"semi_diameter\" {sd} exceeds the curved image surface (radius {})",
                    1.0 / image_curvature
                ));
            }
        }
        let lens = Lens {
            name,
            surfaces,
            media,
            stop,
            aperture,
            fields_deg,
            wavelengths_nm,
            weights,
            primary_nm,
            image_z: z,
            image_semi_diameter,
            image_curvature,
            object_distance,
        };
        lens.check_geometry()?;
        Ok(lens)
    }

    /// Surfaces that cross each other on axis or within their clear apertures.
    fn check_geometry(&self) -> Result<()> {
        for (i, pair) in self.surfaces.windows(2).enumerate() {
            let (a, b) = (&pair[0], &pair[1]);
            // Check the vertex and, when both have clear apertures, the smaller one's edge.
            let mut radii = vec![0.0];
            if let (Some(ra), Some(rb)) = (a.semi_diameter, b.semi_diameter) {
                let r = ra.min(rb);
                radii.extend([0.5 * r, r]);
            }
            for r in radii {
                let (Some(sa), Some(sb)) = (crate::surface::sag(a, r * r), crate::surface::sag(b, r * r)) else {
                    continue;
                };
                let gap = a.thickness + sb - sa;
                if gap < -1e-9 {
                    return lens_err(format!(
                        "surfaces {} and {} cross at height {r:.3} mm (thickness {} leaves a gap of {gap:.4} mm)",
                        i + 1,
                        i + 2,
                        a.thickness
                    ));
                }
            }
        }
        Ok(())
    }

    /// Index of every medium at `wl_nm` (element 0: object space).
    pub fn indices(&self, wl_nm: f64) -> Result<Vec<f64>> {
        self.media
            .iter()
            .enumerate()
            .map(|(i, m)| {
                m.index(wl_nm * 1e-3).map_err(|e| match e {
                    EngineError::Material(msg) if i > 0 => {
                        EngineError::Material(format!("surface {} (medium after it): {msg}", i))
                    }
                    other => other,
                })
            })
            .collect()
    }

    pub fn max_field_deg(&self) -> f64 {
        self.fields_deg.iter().fold(0.0f64, |m, f| m.max(f.abs()))
    }

    pub fn total_track(&self) -> f64 {
        self.image_z
    }

    /// Whether the object is at a finite distance.
    pub fn finite_object(&self) -> bool {
        self.object_distance.is_finite()
    }
}
