//! nimbus: particle clouds (Position Based Fluids + cloud thermodynamics, adaptive particles)
//! simulated on the GPU with wgpu, splatted on the CPU, written as OpenVDB / OpenEXR sequences.
pub mod bench;
pub mod config;
pub mod error;
pub mod export;
pub mod farm;
/// Fault points for the crash tests (`NIMBUS_FAULT`); inert unless built with `test-hooks`.
mod fault;
pub mod gpu;
pub mod ground;
pub mod io;
pub mod pipeline;
pub mod preview;
pub mod shot;
pub mod sim;
pub mod splat;
pub mod stdout;

pub use error::{Error, Result};

/// Version written into manifests, checkpoints and VDB metadata.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
