//! Files: atomic writes, VDB and EXR writers, PLY particle caches, checkpoints, `inspect`, and
//! the greyscale heat maps of image sources.
pub mod atomic;
pub mod checkpoint;
pub mod exr;
pub mod heat_map;
pub mod inspect;
pub mod nanovdb;
pub mod obj;
pub mod ply;
pub mod vdb;
