//! Optical materials: constant index, model glass (nd, Vd) and the dispersion formulas of
//! the refractiveindex.info database (formulas 1-9, wavelength in micrometres), plus
//! tabulated n(lambda). Catalog names are resolved on the Python side.

use crate::error::{EngineError, Result};

/// Fraunhofer d, F and C lines (micrometres) used by the model glass.
const LAMBDA_D: f64 = 0.5875618;
const LAMBDA_F: f64 = 0.4861327;
const LAMBDA_C: f64 = 0.6562725;

#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    Air,
    Constant(f64),
    /// Model glass: two-term Cauchy n = A + B / lambda^2 through nd with nF - nC = (nd-1)/Vd.
    Model {
        nd: f64,
        vd: f64,
    },
    /// refractiveindex.info formula `kind` (1-9) with its coefficient list.
    Formula {
        kind: u8,
        coefficients: Vec<f64>,
        range_um: Option<(f64, f64)>,
        name: String,
    },
    /// Tabulated n, linearly interpolated (wavelengths ascending, micrometres).
    Tabulated {
        wavelength_um: Vec<f64>,
        n: Vec<f64>,
        name: String,
    },
}

impl Material {
    pub fn name(&self) -> String {
        match self {
            Material::Air => "air".into(),
            Material::Constant(n) => format!("n={n}"),
            Material::Model { nd, vd } => format!("model nd={nd} vd={vd}"),
            Material::Formula { name, .. } | Material::Tabulated { name, .. } => name.clone(),
        }
    }

    /// Check coefficients once, at load time, so that `index` only fails on range.
    pub fn validate(&self) -> std::result::Result<(), String> {
        match self {
            Material::Air => Ok(()),
            Material::Constant(n) => {
                if n.is_finite() && *n > 0.0 {
                    Ok(())
                } else {
                    Err(format!("constant index n={n} must be finite and positive"))
                }
            }
            Material::Model { nd, vd } => {
                if !(nd.is_finite() && *nd > 1.0) {
                    Err(format!("model glass nd={nd} must be finite and > 1"))
                } else if !(vd.is_finite() && *vd > 0.0) {
                    Err(format!("model glass vd={vd} must be finite and > 0"))
                } else {
                    Ok(())
                }
            }
            Material::Formula {
                kind,
                coefficients,
                range_um,
                ..
            } => {
                if !(1..=9).contains(kind) {
                    return Err(format!(
                        "dispersion formula {kind} is not one of refractiveindex.info's 1-9"
                    ));
                }
                if coefficients.is_empty() || coefficients.iter().any(|c| !c.is_finite()) {
                    return Err("dispersion coefficients must be a non-empty list of finite numbers".into());
                }
                if let Some((lo, hi)) = range_um {
                    if !(lo.is_finite() && hi.is_finite() && lo < hi && *lo > 0.0) {
                        return Err(format!("range_um [{lo}, {hi}] is not an increasing positive range"));
                    }
                }
                Ok(())
            }
            Material::Tabulated { wavelength_um, n, .. } => {
                if wavelength_um.len() < 2 || wavelength_um.len() != n.len() {
                    return Err("tabulated material needs at least two (wavelength, n) rows".into());
                }
                if wavelength_um.windows(2).any(|w| !(w[1] > w[0])) {
                    return Err("tabulated wavelengths must be strictly increasing".into());
                }
                if n.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                    return Err("tabulated n must be finite and positive".into());
                }
                Ok(())
            }
        }
    }

    /// Refractive index at `wl_um` micrometres.
    pub fn index(&self, wl_um: f64) -> Result<f64> {
        let bad = |msg: String| Err(EngineError::Material(format!("{}: {msg}", self.name())));
        if !(wl_um.is_finite() && wl_um > 0.0) {
            return bad(format!("wavelength {wl_um} um is not positive"));
        }
        let n = match self {
            Material::Air => 1.0,
            Material::Constant(n) => *n,
            Material::Model { nd, vd } => {
                let b = (nd - 1.0) / vd / (LAMBDA_F.powi(-2) - LAMBDA_C.powi(-2));
                let a = nd - b / (LAMBDA_D * LAMBDA_D);
                a + b / (wl_um * wl_um)
            }
            Material::Formula {
                kind,
                coefficients,
                range_um,
                ..
            } => {
                if let Some((lo, hi)) = range_um {
                    if let Some(m) = out_of_range(wl_um, *lo, *hi, "the formula's valid range") {
                        return bad(m);
                    }
                }
                formula(*kind, coefficients, wl_um)
            }
            Material::Tabulated { wavelength_um, n, .. } => {
                let (lo, hi) = (wavelength_um[0], *wavelength_um.last().unwrap());
                if let Some(m) = out_of_range(wl_um, lo, hi, "the table") {
                    return bad(m);
                }
                // Inside the table: linear interpolation; just past an end: the end segment extended.
                let i = wavelength_um
                    .partition_point(|&w| w < wl_um)
                    .clamp(1, wavelength_um.len() - 1);
                let t = (wl_um - wavelength_um[i - 1]) / (wavelength_um[i] - wavelength_um[i - 1]);
                n[i - 1] + t * (n[i] - n[i - 1])
            }
        };
        if n.is_finite() && n > 0.0 {
            Ok(n)
        } else {
            bad(format!("index evaluates to {n} at {:.1} nm", wl_um * 1e3))
        }
    }
}

/// How far past either end of its data a material is extrapolated, as a fraction of the
/// data's span (OpticStudio likewise extrapolates a little with a warning; the Python side
/// reports each extrapolation, see `optix_e2e.glass.range_note`). Further out: an error.
pub const EXTRAPOLATION_FRACTION: f64 = 0.1;

/// The message for a wavelength (micrometres) farther than EXTRAPOLATION_FRACTION of the
/// span outside [lo, hi], if it is.
fn out_of_range(wl_um: f64, lo: f64, hi: f64, what: &str) -> Option<String> {
    let slack = EXTRAPOLATION_FRACTION * (hi - lo);
    (wl_um < lo - slack || wl_um > hi + slack).then(|| {
        format!(
            "wavelength {:.1} nm is outside {what} {:.1}-{:.1} nm (extrapolated at most {:.0}% of the span, to {:.1}-{:.1} nm)",
            wl_um * 1e3, lo * 1e3, hi * 1e3, EXTRAPOLATION_FRACTION * 100.0, (lo - slack) * 1e3, (hi + slack) * 1e3
        )
    })
}

/// Coefficient `i` (0-based) or 0 when the list is shorter: the database omits trailing zeros.
fn c(cs: &[f64], i: usize) -> f64 {
    cs.get(i).copied().unwrap_or(0.0)
}

/// sum of C_i l^C_{i+1} over coefficient pairs starting at index `from`.
fn power_terms(cs: &[f64], from: usize, l: f64) -> f64 {
    cs.get(from..)
        .unwrap_or(&[])
        .chunks(2)
        .map(|p| p[0] * l.powf(p.get(1).copied().unwrap_or(0.0)))
        .sum()
}

/// The refractiveindex.info dispersion formulas (database documentation, "formula 1".."9").
fn formula(kind: u8, cs: &[f64], l: f64) -> f64 {
    let l2 = l * l;
    match kind {
        // 1: Sellmeier, n^2 - 1 = C1 + sum C_i l^2 / (l^2 - C_{i+1}^2)
        1 => {
            let mut s = 1.0 + c(cs, 0);
            let mut i = 1;
            while i < cs.len() {
                s += c(cs, i) * l2 / (l2 - c(cs, i + 1).powi(2));
                i += 2;
            }
            s.sqrt()
        }
        // 2: Sellmeier-2, n^2 - 1 = C1 + sum C_i l^2 / (l^2 - C_{i+1})
        2 => {
            let mut s = 1.0 + c(cs, 0);
            let mut i = 1;
            while i < cs.len() {
                s += c(cs, i) * l2 / (l2 - c(cs, i + 1));
                i += 2;
            }
            s.sqrt()
        }
        // 3: polynomial, n^2 = C1 + sum C_i l^C_{i+1}
        3 => (c(cs, 0) + power_terms(cs, 1, l)).sqrt(),
        // 4: RefractiveIndex.INFO, two Sellmeier-like terms then polynomial terms from C10 on
        4 => {
            let mut s = c(cs, 0);
            if cs.len() > 1 {
                s += c(cs, 1) * l.powf(c(cs, 2)) / (l2 - c(cs, 3).powf(c(cs, 4)));
            }
            if cs.len() > 5 {
                s += c(cs, 5) * l.powf(c(cs, 6)) / (l2 - c(cs, 7).powf(c(cs, 8)));
            }
            (s + power_terms(cs, 9, l)).sqrt()
        }
        // 5: Cauchy, n = C1 + sum C_i l^C_{i+1}
        5 => c(cs, 0) + power_terms(cs, 1, l),
        // 6: gases, n - 1 = C1 + sum C_i / (C_{i+1} - l^-2)
        6 => {
            let mut s = 1.0 + c(cs, 0);
            let mut i = 1;
            while i < cs.len() {
                s += c(cs, i) / (c(cs, i + 1) - 1.0 / l2);
                i += 2;
            }
            s
        }
        // 7: Herzberger
        7 => {
            let d = 1.0 / (l2 - 0.028);
            c(cs, 0) + c(cs, 1) * d + c(cs, 2) * d * d + c(cs, 3) * l2 + c(cs, 4) * l2 * l2 + c(cs, 5) * l2 * l2 * l2
        }
        // 8: retro, (n^2-1)/(n^2+2) = C1 + C2 l^2/(l^2-C3) + C4 l^2
        8 => {
            let r = c(cs, 0) + c(cs, 1) * l2 / (l2 - c(cs, 2)) + c(cs, 3) * l2;
            ((1.0 + 2.0 * r) / (1.0 - r)).sqrt()
        }
        // 9: exotic, n^2 = C1 + C2/(l^2-C3) + C4 (l-C5)/((l-C5)^2 + C6)
        9 => {
            let s =
                c(cs, 0) + c(cs, 1) / (l2 - c(cs, 2)) + c(cs, 3) * (l - c(cs, 4)) / ((l - c(cs, 4)).powi(2) + c(cs, 5));
            s.sqrt()
        }
        _ => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_glass_hits_nd_and_abbe_number() {
        let m = Material::Model { nd: 1.5168, vd: 64.17 };
        let nd = m.index(LAMBDA_D).unwrap();
        let nf = m.index(LAMBDA_F).unwrap();
        let nc = m.index(LAMBDA_C).unwrap();
        assert!((nd - 1.5168).abs() < 1e-12);
        assert!(((nd - 1.0) / (nf - nc) - 64.17).abs() < 1e-9);
    }

    #[test]
    fn out_of_range_wavelength_is_an_error_naming_the_glass() {
        let m = Material::Formula {
            kind: 2,
            coefficients: vec![0.0, 1.0, 0.01],
            range_um: Some((0.4, 0.7)),
            name: "X1".into(),
        };
        let e = m.index(0.9).unwrap_err().to_string();
        assert!(e.contains("X1") && e.contains("900.0 nm"), "{e}");
    }

    #[test]
    fn data_is_extrapolated_up_to_a_tenth_of_its_span_past_either_end() {
        // Table 3-14 um (span 11): 2.5 um is 0.5 past the end, inside the 1.1 allowed.
        let t = Material::Tabulated {
            wavelength_um: vec![3.0, 4.0, 14.0],
            n: vec![2.5, 2.4, 2.3],
            name: "t".into(),
        };
        assert!((t.index(2.5).unwrap() - 2.55).abs() < 1e-12); // first segment extended
        assert!((t.index(15.0).unwrap() - 2.29).abs() < 1e-12); // last segment extended
        assert!(t.index(1.85).unwrap_err().to_string().contains("1900.0-15100.0 nm"));
        // Formula valid 0.4-0.7 um (span 0.3): evaluated to 0.37 and 0.73, an error beyond.
        let f = Material::Formula {
            kind: 5,
            coefficients: vec![1.5, 0.01, -2.0],
            range_um: Some((0.4, 0.7)),
            name: "F".into(),
        };
        assert!((f.index(0.372).unwrap() - (1.5 + 0.01 / (0.372 * 0.372))).abs() < 1e-12);
        assert!(f.index(0.728).is_ok() && f.index(0.365).is_err() && f.index(0.735).is_err());
    }

    #[test]
    fn tabulated_interpolates_linearly() {
        let m = Material::Tabulated {
            wavelength_um: vec![0.5, 0.6],
            n: vec![1.5, 1.4],
            name: "t".into(),
        };
        assert!((m.index(0.55).unwrap() - 1.45).abs() < 1e-15);
    }
}
