//! Errors of the engine. Each variant names what went wrong precisely enough for a user
//! to find it: the surface index (1-based, as lens designers count) and the parameter.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum EngineError {
    /// Invalid prescription: a message naming the surface and parameter at fault.
    #[error("lens: {0}")]
    Lens(String),
    /// A material that cannot give an index (bad formula, wavelength out of range).
    #[error("material: {0}")]
    Material(String),
    /// A trace that cannot produce a result (chief ray lost, aiming diverged).
    #[error("trace: {0}")]
    Trace(String),
    /// A PSF that cannot be computed.
    #[error("psf: {0}")]
    Psf(String),
    /// A bad argument to an engine call (sizes, sample counts, method names).
    #[error("argument: {0}")]
    Argument(String),
}

pub type Result<T> = std::result::Result<T, EngineError>;

pub(crate) fn arg<T>(msg: impl Into<String>) -> Result<T> {
    Err(EngineError::Argument(msg.into()))
}
