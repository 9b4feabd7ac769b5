//! psf-engine: exact sequential ray tracing through rotationally symmetric compound
//! lenses, and their point spread functions (geometric, FFT of the pupil function,
//! Huygens). Pure Rust; the Python bindings live in the psf-engine-py crate.

// `!(x > 0.0)` refuses a NaN together with the values out of range: the engine's checks
// are written that way on purpose.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// PSF options and ray arrays are passed field by field at the crate's edges; a struct for
// each call would only move the list.
#![allow(clippy::too_many_arguments)]

// Lets unit tests share tests/common, which refers to this crate by name.
#[cfg(test)]
extern crate self as psf_engine;

pub mod aim;
pub mod budget;
pub mod error;
pub mod focus;
pub mod gradient;
pub mod image;
pub mod kernel;
pub mod lens;
pub mod material;
pub mod paraxial;
pub mod psf;
pub mod rgb;
pub mod spot;
pub mod surface;
pub mod tangent;
pub mod trace;
pub mod wavefront;

pub use aim::{Aiming, Beam};
pub use error::{EngineError, Result};
pub use lens::Lens;
pub use paraxial::{paraxial, Paraxial};
pub use trace::{End, RayState, Status, System, Traced};
