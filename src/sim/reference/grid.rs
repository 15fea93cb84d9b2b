//! f64 mirror of shaders/grid.wgsl (`cell_keys`, `cell_scatter` and `cell_order`), the
//! neighbour-grid build they compose with the scan, and the 27-cell neighbour walks of the other
//! mirrors: the host's own neighbour table (`sim::cell_table`), which is the same algorithm.
pub use crate::sim::cell_table::*;
