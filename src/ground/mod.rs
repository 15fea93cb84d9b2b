//! The ground floor: the plain data that the simulation, the splat, the writers and the previews
//! all hold. It imports no other module of the crate (tests/layering.rs keeps it so).
//! - `particles`: the particle set on the host (what checkpoints store and the splat reads);
//! - `clock`: where a simulation stands in time;
//! - `rest`: rest positions, their codec and their reset schedule (`export.detail`);
//! - `grid`: sparse voxel grids of 8^3 leaves and their world transform;
//! - `noise`: the hash and value noise both the GPU step and the detail evaluate.
pub mod clock;
pub mod grid;
pub mod noise;
pub mod particles;
pub mod rest;

pub use clock::SimClock;
pub use grid::{GridTransform, Leaf, SparseGrid, LEAF_DIM, LEAF_VOXELS};
pub use particles::ParticleState;
