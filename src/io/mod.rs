//! Files: atomic writes, frame naming, VDB and EXR writers, PLY particle caches, checkpoint format.
pub mod atomic;
pub mod checkpoint;
pub mod exr;
pub mod inspect;
pub mod ply;
pub mod vdb;
