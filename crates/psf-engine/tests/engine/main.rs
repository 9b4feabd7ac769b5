//! The engine's integration tests, one test binary (one module per file here): a binary per
//! file compiled and linked the library a dozen times, which was most of `cargo test`'s time.
#[path = "../common/mod.rs"]
mod common;

mod aiming;
mod curved_image;
mod failure_modes;
mod fast_adjoint;
mod fast_batch;
mod finite_object;
mod geometric;
mod gradient;
mod illumination;
mod kernel;
mod odd_asphere;
mod path;
mod psf_reference;
mod reference;
mod tangent;
mod traced;
mod wavefront;
