//! Particle state and the simulation step. Each stage of the substep (`stage::Stage`) is a
//! module (`pbf`, `grid`, `smoothing`, `thermo`, `adaptive`, the forces of their own under
//! `forces`), running `gpu::program::Program`s and bound once to the particle buffers
//! (`buffers`); `step` holds the stages and the order of a substep, `simulation` the frame loop
//! and its one read-back, `phase` the phases and their timings, `forces` the list of every
//! force; `reference` the f64 mirror of every shader, file for file.
//!
//! Contract between the GPU stages (see docs/ARCHITECTURE.md):
//! - particle arrays are SoA storage buffers of length `capacity`, the first `count` live;
//!   after each neighbour-grid build they are permuted into cell order;
//! - `pos`: xyz position (w unused), `vel`: xyz velocity (w unused),
//!   `thermo`: (temperature K, vapor, cloud, shape energy), `info`: (id, level);
//! - level l gives h = h0 * 2^(-l/3) and m = m0 * 2^(-l);
//! - boundary particles (floor and ceiling walls) live in their own static arrays.
pub mod adaptive;
pub mod buffers;
pub mod cell_table;
pub mod control;
pub mod diagnostics;
pub mod footprint;
pub mod forces;
pub mod frame_report;
pub mod grid;
pub mod grid_params;
#[cfg(feature = "test-hooks")]
pub mod hooks;
pub mod init;
pub mod kernels;
pub mod pbf;
pub mod phase;
pub mod reference;
pub mod rest;
mod simulation;
pub mod smoothing;
pub mod source_field;
pub mod sources;
pub mod stage;
mod step;
pub mod thermo;
pub mod wind;

pub use frame_report::{FrameReport, StepDiagnostics};
pub use phase::{Phase, PhaseTimes, Timing};
pub use simulation::{
    compression_error, density_error, iterations_in_substep, iterations_per_substep, speed_ratio,
    Simulation,
};
