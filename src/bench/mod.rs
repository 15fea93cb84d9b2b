//! Measurement commands: figures for docs/PERFORMANCE.md, never timed tests.
pub mod checkpoint;
