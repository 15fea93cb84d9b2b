//! Files: atomic writes, frame naming, VDB and EXR writers, checkpoint format.
pub mod atomic;
pub mod checkpoint;
pub mod exr;
pub mod inspect;
pub mod vdb;
