//! psf-engine: exact sequential ray tracing through rotationally symmetric compound
//! lenses, and their point spread functions (geometric, FFT of the pupil function,
//! Huygens). Pure Rust; the Python bindings live in the psf-engine-py crate.

// Lets unit tests share tests/common, which refers to this crate by name.
#[cfg(test)]
extern crate self as psf_engine;

pub mod aim;
pub mod budget;
pub mod error;
pub mod focus;
pub mod image;
pub mod kernel;
pub mod lens;
pub mod material;
pub mod paraxial;
pub mod psf;
pub mod rgb;
pub mod spot;
pub mod surface;
pub mod trace;
pub mod wavefront;

pub use aim::{Aiming, Beam};
pub use error::{EngineError, Result};
pub use lens::Lens;
pub use paraxial::{paraxial, Paraxial};
pub use trace::{End, RayState, Status, System, Traced};
