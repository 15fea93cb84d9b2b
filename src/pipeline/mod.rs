//! The frame loop Simulate (GPU) -> Splat (CPU) -> Write, checkpoint policy, progress, records.
pub mod naming;
pub mod progress;
pub mod records;
