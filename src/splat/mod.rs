//! CPU splatting (rayon) of particle fields onto sparse 8^3-leaf grids.
pub mod grid;
pub use grid::{GridTransform, Leaf, SparseGrid, LEAF_DIM, LEAF_VOXELS};
