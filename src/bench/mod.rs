//! Measurement commands (`nimbus bench ...`): figures go to docs/PERFORMANCE.md, never into tests.
pub mod pbf;
