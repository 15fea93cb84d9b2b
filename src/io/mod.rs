//! Files: atomic writes, frame naming, VDB and EXR writers, PLY particle caches, checkpoint format,
//! the greyscale heat maps of image sources.
pub mod atomic;
pub mod checkpoint;
pub mod exr;
pub mod heat_map;
pub mod inspect;
pub mod ply;
pub mod vdb;
