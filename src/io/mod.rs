//! Files: atomic writes, VDB and EXR writers, PLY particle caches, checkpoints, and `inspect`.
pub mod atomic;
pub mod checkpoint;
pub mod exr;
pub mod inspect;
pub mod ply;
pub mod vdb;
