//! Measurement entry points (no timing assertions anywhere: these only report figures).
pub mod preview;
pub mod splat;
