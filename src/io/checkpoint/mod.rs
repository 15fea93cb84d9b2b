//! Checkpoint files: the whole simulation state of one frame, versioned and checksummed, so a run
//! killed at any point resumes bit for bit.
//!
//! - [`format`]: the bytes of one checkpoint (header, sections, checksums), encoded and decoded.
//! - [`store`]: checkpoint files in a directory: names, atomic writes, pruning, listing.
//! - [`resume`]: finding the newest valid checkpoint of a directory to resume from.
//!
//! # File name
//! `ckpt_<frame>.nck` with the frame zero-padded to 6 digits (`ckpt_000120.nck`), one per
//! checkpointed frame, in the run's checkpoint directory. Files are written through
//! [`crate::io::atomic`] (temporary `*.nimbus-tmp` beside it, fsync, rename, directory fsync),
//! so a checkpoint file is either complete or absent; the checksums catch everything else
//! (a disk that lies, a copy cut short, a file edited by hand).
pub mod format;
pub mod resume;
pub mod store;

pub use format::{
    config_of, decode, is_checkpoint, read_checkpoint, read_header, Checkpoint, CheckpointHeader,
    CONFIG_SECTION, FORMAT_VERSION, MAGIC, STATE_SECTIONS,
};
pub use resume::{
    find_resumable, newest_config, scan_resumable, Found, ResumeScan, SkipReason, Skipped,
};
#[cfg(feature = "test-hooks")]
pub use store::write_checkpoint_failing_after;
pub use store::{
    file_name, frame_of_name, list_checkpoints, prune, write_and_prune, write_checkpoint, EXTENSION,
};
