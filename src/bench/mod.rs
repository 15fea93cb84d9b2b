//! Measurement commands (`nimbus bench ...`): timings go here, never into tests.
pub mod vdb;
