//! f64 CPU mirrors of the GPU stages, same names as the shaders; used by tests.
pub mod grid;
pub mod kernels;
pub mod pbf;
pub mod sort;
