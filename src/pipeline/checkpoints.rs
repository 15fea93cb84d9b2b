//! The run's checkpoints: the one a resume goes on from (the newest valid one of the same
//! simulation config inside the frame range), how far into the pre-roll it was taken, and
//! writing one after a frame (with the resolved config, the rest positions and the pre-roll
//! mark as extra sections).
use crate::config::{self, ShotConfig};
use crate::error::{Error, Result};
use crate::ground::ParticleState;
use crate::io::checkpoint::{self, Checkpoint, ResumeScan, SkipReason};
use crate::sim::rest::{self, RestTracker};
use crate::sim::Simulation;
use std::path::{Path, PathBuf};

/// The checkpoint of `ckpt_dir` a run of `cfg` (sim hash `sim_hash`) resumes from: the newest
/// valid one of the same simulation config whose frame lies in the config's frame range. The
/// files passed over are warned about on stderr.
pub fn checkpoint_to_resume(
    cfg: &ShotConfig,
    ckpt_dir: &Path,
    sim_hash: &str,
) -> Result<Checkpoint> {
    let scan = checkpoint::scan_resumable(ckpt_dir, sim_hash)?;
    let skipped: Vec<String> = scan.skipped.iter().map(|s| s.to_string()).collect();
    for s in &skipped {
        eprintln!("warning: skipped checkpoint: {s}");
    }
    if scan.found.is_none() && scan.config_changed() {
        return Err(changed_keys_error(cfg, &scan));
    }
    match scan.found {
        Some((path, ck)) => {
            check_resume_frame(cfg, &path, ck.header.frame)?;
            eprintln!(
                "resuming from {} (frame {})",
                path.display(),
                ck.header.frame
            );
            Ok(ck)
        }
        None => Err(Error::InvalidInput(format!(
            "{}: no usable checkpoint to resume from{}",
            ckpt_dir.display(),
            if skipped.is_empty() {
                ""
            } else {
                " (see the warnings above)"
            }
        ))),
    }
}

/// No checkpoint matches the config's simulation keys: name every key that differs from the
/// newest checkpoint that records its config.
fn changed_keys_error(cfg: &ShotConfig, scan: &ResumeScan) -> Error {
    for s in &scan.skipped {
        if !matches!(s.reason, SkipReason::ConfigMismatch { .. }) {
            continue;
        }
        if let Some(recorded) = checkpoint::read_checkpoint(&s.path)
            .ok()
            .and_then(|ck| checkpoint::config_of(&ck))
        {
            let diff = config::sim_key_diff(&recorded, cfg);
            if !diff.is_empty() {
                return Error::InvalidInput(format!(
                    "{}: cannot resume: simulation keys differ from the checkpoint's: {}",
                    s.path.display(),
                    diff.join(", ")
                ));
            }
        }
    }
    Error::InvalidInput(
        "cannot resume: the simulation config differs from every checkpoint's (see the warnings above)"
            .into(),
    )
}

/// A checkpoint resumes only inside the frame range: one past `frames.end` (the range was
/// lowered after it was written) or before `frames.start` is refused before anything is written.
fn check_resume_frame(cfg: &ShotConfig, path: &Path, frame: u32) -> Result<()> {
    let (start, end) = (cfg.output.frames.start, cfg.output.frames.end);
    if frame > end {
        return Err(Error::InvalidInput(format!(
            "{}: cannot resume: the newest usable checkpoint holds frame {frame}, past \
             output.frames.end = {end}; the run already went beyond that end: raise \
             output.frames.end to {frame} or more (nimbus run CONFIG --out DIR --resume --set \
             output.frames.end=N)",
            path.display()
        )));
    }
    if frame < start {
        return Err(Error::InvalidInput(format!(
            "{}: cannot resume: the checkpoint holds frame {frame}, before output.frames.start = \
             {start}",
            path.display()
        )));
    }
    Ok(())
}

/// Checkpoint section of a checkpoint taken during the pre-roll: JSON `{"done": k, "frames":
/// P}`, k of the P pre-roll frames simulated. Such a checkpoint is named after (and its header
/// holds) `frames.start`, the frame the run writes first; the real checkpoint of that frame
/// replaces it.
pub const PREROLL_SECTION: &str = "preroll";

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub(super) struct PrerollMark {
    pub done: u32,
    pub frames: u32,
}

/// How many pre-roll frames `ck` had simulated (`None`: it is a checkpoint of a written frame,
/// after the pre-roll). A checkpoint of another pre-roll length cannot be resumed (the sim hash
/// already refuses it; this names why).
pub(super) fn preroll_progress(ck: &Checkpoint, preroll: u32) -> Result<Option<u32>> {
    let Some(bytes) = ck.extra.get(PREROLL_SECTION) else {
        return Ok(None);
    };
    let mark: PrerollMark = serde_json::from_slice(bytes).map_err(|e| {
        Error::InvalidInput(format!(
            "checkpoint of frame {}: unreadable pre-roll section: {e}",
            ck.header.frame
        ))
    })?;
    if mark.frames != preroll || mark.done > mark.frames {
        return Err(Error::InvalidInput(format!(
            "checkpoint of frame {}: taken in pre-roll frame {} of {}, but the run's pre-roll is {preroll} frames",
            ck.header.frame, mark.done, mark.frames
        )));
    }
    Ok(Some(mark.done))
}

#[allow(clippy::too_many_arguments)]
pub(super) fn write_checkpoint(
    cfg: &ShotConfig,
    dir: &Path,
    sim_hash: &str,
    adapter: &str,
    state: &ParticleState,
    preroll: Option<PrerollMark>,
    rest: Option<&RestTracker>,
    frame: u32,
    sim: &Simulation,
) -> Result<PathBuf> {
    let mut extra: std::collections::BTreeMap<String, Vec<u8>> = [(
        checkpoint::CONFIG_SECTION.to_string(),
        serde_json::to_vec_pretty(cfg).map_err(|e| Error::Runtime(e.to_string()))?,
    )]
    .into();
    if let Some(r) = rest {
        extra.insert(rest::CHECKPOINT_SECTION.to_string(), r.to_bytes());
    }
    if let Some(m) = preroll {
        extra.insert(
            PREROLL_SECTION.to_string(),
            serde_json::to_vec(&m).map_err(|e| Error::Runtime(e.to_string()))?,
        );
    }
    let clock = sim.clock();
    let ck = Checkpoint {
        header: checkpoint::CheckpointHeader {
            tool_version: crate::VERSION.to_string(),
            sim_hash: sim_hash.to_string(),
            frame,
            step: clock.step,
            time: clock.time,
            seed: cfg.seed,
            particle_count: state.len() as u64,
            capacity: sim.capacity() as u64,
            adapter: adapter.to_string(),
            next_id: clock.next_id,
        },
        state: state.clone(),
        // The resolved config, so a run whose manifest was lost can still be resumed, and the
        // rest positions when the run tracks them.
        extra,
    };
    checkpoint::write_and_prune(dir, &ck, cfg.checkpoint.keep as usize)
}
