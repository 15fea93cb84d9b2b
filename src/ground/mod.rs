//! The ground floor: the plain data that the simulation, the splat, the writers and the previews
//! all hold. It imports no other module of the crate (tests/layering.rs keeps it so).
//! - `particles`: the particle set on the host (what checkpoints store and the splat reads);
//! - `clock`: where a simulation stands in time;
//! - `rest`: rest positions, their codec and their reset schedule (`export.detail`);
//! - `grid`: sparse voxel grids of 8^3 leaves and their world transform;
//! - `noise`: the hash and value noise both the GPU step and the detail evaluate;
//! - `heat_map`: a decoded heat map of an image source;
//! - `limits`: the sizes of the thermo uniform's tables (sources, wind levels, layers);
//! - `levels`: the adaptive levels (the finest, a level's kernel radius and mass) and the poly6
//!   kernel they are measured with;
//! - `voxels`: the coarse voxel grid of `control.target` and the target's voxels on it.
pub mod clock;
pub mod grid;
pub mod heat_map;
pub mod levels;
pub mod limits;
pub mod noise;
pub mod particles;
pub mod rest;
pub mod voxels;

pub use clock::SimClock;
pub use grid::{GridTransform, Leaf, SparseGrid, LEAF_DIM, LEAF_VOXELS};
pub use heat_map::HeatMap;
pub use particles::ParticleState;
pub use voxels::{TargetVoxels, VoxelGrid, MAX_VOXELS};
