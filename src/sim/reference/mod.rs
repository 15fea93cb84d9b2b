//! f64 CPU mirrors of the GPU stages, same names as the shaders; used by tests.
pub mod adaptive;
pub mod grid;
pub mod kernels;
pub mod pbf;
pub mod smoothing;
pub mod sort;
pub mod thermo;
