//! Nothing here: the benchmarks are in benches/engine.rs (`cargo bench -p psf-engine-bench`).
