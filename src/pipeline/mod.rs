//! The frame loop Simulate (GPU) -> Splat (CPU) -> Write, checkpoint policy, progress, records.
pub mod checkpoints;
pub mod lock;
pub mod naming;
pub mod open;
pub mod particle_view;
pub mod progress;
pub mod records;
pub mod reexport;
pub mod rerender;
pub mod resume;
pub mod run;
pub mod run_dir;
pub mod survey;
pub mod usd_layer;
pub mod watchdog;
pub mod writer;

pub use open::{RunOptions, Start};
pub use progress::LogFormat;
pub use run::{run, run_fresh};
