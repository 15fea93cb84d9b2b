//! Checkpoint files in a directory: their names, writing (atomic), pruning and listing.
use super::format::{Checkpoint, Encoded};
use crate::error::{Error, Result};
use crate::io::atomic;
use std::fs;
use std::path::{Path, PathBuf};

/// File name extension.
pub const EXTENSION: &str = "nck";

/// `ckpt_<frame zero-padded to 6>.nck`.
pub fn file_name(frame: u32) -> String {
    format!("ckpt_{frame:06}.{EXTENSION}")
}

/// The frame a checkpoint file name stands for, `None` for any other name.
pub fn frame_of_name(name: &str) -> Option<u32> {
    let digits = name
        .strip_prefix("ckpt_")?
        .strip_suffix(EXTENSION)?
        .strip_suffix('.')?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// Writes `ck` as `dir/ckpt_<frame>.nck` atomically (temporary file, fsync, rename, directory
/// fsync) and returns its path. `dir` is created if missing. A write error (disk full, ...) is
/// `Error::Io` naming the checkpoint path and the reason; the previous checkpoints are untouched
/// and no temporary file is left. An inconsistent `ck` (array lengths, reserved or invalid extra
/// section names) is `Error::Runtime`: it is a bug of the caller, not of the disk.
pub fn write_checkpoint(dir: &Path, ck: &Checkpoint) -> Result<PathBuf> {
    write_impl(dir, ck, None)
}

/// [`write_checkpoint`], then removes the checkpoints of later frames (left by an abandoned
/// timeline: the run resumed from before them, so they no longer match what it computes) and
/// prunes to the newest `keep` (at least 1). The one just written is the newest, so it is kept.
pub fn write_and_prune(dir: &Path, ck: &Checkpoint, keep: usize) -> Result<PathBuf> {
    let path = write_checkpoint(dir, ck)?;
    for (frame, p) in list_checkpoints(dir)? {
        if frame > ck.header.frame {
            fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
        }
    }
    prune(dir, keep)?;
    Ok(path)
}

/// Test hook: like [`write_checkpoint`], but the temporary file fails with "no space left on
/// device" once `fail_after` bytes have gone into it (a disk filling up at any point).
#[cfg(feature = "test-hooks")]
pub fn write_checkpoint_failing_after(
    dir: &Path,
    ck: &Checkpoint,
    fail_after: u64,
) -> Result<PathBuf> {
    write_impl(dir, ck, Some(fail_after))
}

/// Keeps the newest `keep` checkpoints of `dir` by frame (at least one) and deletes the others;
/// returns the deleted paths. Other files are not touched.
pub fn prune(dir: &Path, keep: usize) -> Result<Vec<PathBuf>> {
    let list = list_checkpoints(dir)?;
    let n_del = list.len().saturating_sub(keep.max(1));
    let mut deleted = Vec::with_capacity(n_del);
    for (_, p) in list.into_iter().take(n_del) {
        fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
        deleted.push(p);
    }
    Ok(deleted)
}

/// Checkpoint files of `dir` (by name), oldest frame first; a missing `dir` has none.
pub fn list_checkpoints(dir: &Path) -> Result<Vec<(u32, PathBuf)>> {
    let rd = match fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut out = Vec::new();
    for entry in rd {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let name = entry.file_name();
        let Some(frame) = name.to_str().and_then(frame_of_name) else {
            continue;
        };
        if entry.file_type().map(|t| t.is_file()).unwrap_or(false) {
            out.push((frame, entry.path()));
        }
    }
    out.sort();
    Ok(out)
}

fn write_impl(dir: &Path, ck: &Checkpoint, fail_after: Option<u64>) -> Result<PathBuf> {
    let encoded = Encoded::new(ck)?;
    fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let path = dir.join(file_name(ck.header.frame));
    atomic::write_atomic_with(&path, |f| encoded.write_to(f, fail_after))?;
    Ok(path)
}
