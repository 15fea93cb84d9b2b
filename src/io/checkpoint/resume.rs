//! Scanning a checkpoint directory, newest frame first, for the checkpoint a run resumes from.
use super::format::{config_of, read_checkpoint, Checkpoint};
use super::store::list_checkpoints;
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Why a checkpoint file was passed over by [`scan_resumable`].
#[derive(Debug, Clone, PartialEq)]
pub enum SkipReason {
    /// Unreadable, corrupt, truncated, foreign, or misnamed: the reason in one line.
    Invalid(String),
    /// A valid checkpoint of a different simulation config (the caller lists the differing keys).
    ConfigMismatch { found: String, expected: String },
}

/// A checkpoint file passed over, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Skipped {
    pub path: PathBuf,
    pub reason: SkipReason,
}

impl std::fmt::Display for Skipped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.reason {
            SkipReason::Invalid(r) => write!(f, "skipping {}: {r}", self.path.display()),
            SkipReason::ConfigMismatch { found, expected } => write!(
                f,
                "skipping {}: simulation config changed (checkpoint sim hash {found}, \
                 config sim hash {expected})",
                self.path.display()
            ),
        }
    }
}

/// A checkpoint chosen for resuming, with its path.
pub type Found = (PathBuf, Checkpoint);

/// Result of looking for a checkpoint to resume from.
#[derive(Debug)]
pub struct ResumeScan {
    /// The newest checkpoint that validates and matches the config, if any.
    pub found: Option<Found>,
    /// Newer checkpoint files passed over, newest first.
    pub skipped: Vec<Skipped>,
}

impl ResumeScan {
    /// Whether some checkpoint was passed over only because the simulation config changed.
    pub fn config_changed(&self) -> bool {
        self.skipped
            .iter()
            .any(|s| matches!(s.reason, SkipReason::ConfigMismatch { .. }))
    }
}

/// Tries the checkpoints of `dir` newest frame first and stops at the first one that validates,
/// whose header frame matches its file name and whose sim hash is `expected_sim_hash`. Files that
/// fail are listed with their reason; a config mismatch is a `SkipReason::ConfigMismatch` and the
/// search goes on to older files. Temporary files and other names are ignored. Only a directory
/// that exists but cannot be listed is an error.
pub fn scan_resumable(dir: &Path, expected_sim_hash: &str) -> Result<ResumeScan> {
    let mut list = list_checkpoints(dir)?;
    list.reverse();
    let mut skipped = Vec::new();
    for (frame, path) in list {
        let reason = match read_checkpoint(&path) {
            Err(Error::InvalidInput(msg)) => {
                // `msg` is "<path>: <reason>"; keep the reason only.
                let prefix = format!("{}: ", path.display());
                SkipReason::Invalid(msg.strip_prefix(&prefix).unwrap_or(&msg).to_string())
            }
            Err(Error::Io { source, .. }) => SkipReason::Invalid(format!("cannot read: {source}")),
            Err(e) => SkipReason::Invalid(e.to_string()),
            Ok(ck) if ck.header.frame != frame => SkipReason::Invalid(format!(
                "file name says frame {frame} but the checkpoint holds frame {}",
                ck.header.frame
            )),
            Ok(ck) if ck.header.sim_hash != expected_sim_hash => SkipReason::ConfigMismatch {
                found: ck.header.sim_hash.clone(),
                expected: expected_sim_hash.to_string(),
            },
            Ok(ck) => {
                return Ok(ResumeScan {
                    found: Some((path, ck)),
                    skipped,
                })
            }
        };
        skipped.push(Skipped { path, reason });
    }
    Ok(ResumeScan {
        found: None,
        skipped,
    })
}

/// [`scan_resumable`] with the skipped files as printable lines.
pub fn find_resumable(dir: &Path, expected_sim_hash: &str) -> Result<(Option<Found>, Vec<String>)> {
    let scan = scan_resumable(dir, expected_sim_hash)?;
    let lines = scan.skipped.iter().map(|s| s.to_string()).collect();
    Ok((scan.found, lines))
}

/// The resolved config recorded in the newest checkpoint of `dir` that reads and records one,
/// with its path (`None` when no checkpoint does).
pub fn newest_config(dir: &Path) -> Result<Option<(PathBuf, ShotConfig)>> {
    let mut list = list_checkpoints(dir)?;
    list.reverse();
    Ok(list.into_iter().find_map(|(_, path)| {
        let cfg = read_checkpoint(&path).ok().and_then(|ck| config_of(&ck))?;
        Some((path, cfg))
    }))
}
