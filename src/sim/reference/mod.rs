//! f64 CPU mirrors of the GPU stages, file for file: `<stage>.rs` mirrors `shaders/<stage>.wgsl`
//! with the same entry-point names; `common` holds the helpers of shaders/shared/common.wgsl and
//! shared/adaptive.wgsl, `permute` those of shared/permute.wgsl. Used by tests, and by the host
//! where it needs the same arithmetic (the initial wall particles' grid, diagnostics).
pub mod adaptive;
pub mod adaptive_compact;
pub mod adaptive_mark;
pub mod adaptive_merge;
pub mod adaptive_plan;
pub mod adaptive_split;
pub mod adaptive_stats;
pub mod common;
pub mod coriolis;
pub mod entrainment;
pub mod forcing;
pub mod grid;
pub mod pbf;
pub mod permute;
pub mod scan;
pub mod smoothing;
pub mod thermo;
