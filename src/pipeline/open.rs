//! Opening a run, fresh or resumed, in one place: the directory made ready, the checkpoint a
//! resume goes on from and how far into the pre-roll it was, the device, the `Simulation` (new,
//! or from the checkpoint's state and clock), the rest tracker, and the records (manifest,
//! rebuilt from the files on disk when lost; stats up to the first frame to simulate; the USD
//! layer). What comes out is all the frame loop (`super::run`) needs.
use super::checkpoints::{checkpoint_to_resume, preroll_progress, PREROLL_SECTION};
use super::progress::LogFormat;
use super::records::{Manifest, StatsLog};
use super::run_dir::RunDir;
use super::usd_layer::LayerWriter;
use super::writer::FrameWriter;
use crate::config;
use crate::error::{Error, Result};
use crate::gpu;
use crate::ground::SimClock;
use crate::io::checkpoint::Checkpoint;
use crate::shot::Shot;
use crate::sim::rest::{self, RestTracker};
use crate::sim::Simulation;
use std::path::PathBuf;
use std::sync::Arc;

/// How a run starts.
pub enum Start {
    /// A new run: the simulation starts at the first frame. The directory must be empty of
    /// runs (see `run_dir`); with `force`, an earlier run's own files are removed first.
    Fresh { force: bool },
    /// Go on from the newest valid checkpoint in the run directory.
    Resume,
}

pub struct RunOptions {
    pub out_dir: PathBuf,
    pub log: LogFormat,
    pub start: Start,
    /// The device, opened (and the shot checked against it) before the run directory was
    /// touched; `None`: `run` opens it.
    pub device: Option<Arc<gpu::Context>>,
}

/// A run ready for its frame loop.
pub(super) struct Opened {
    pub sim: Simulation,
    /// The first frame the loop simulates after the pre-roll (`frames.start`, or the one after
    /// the resumed checkpoint's).
    pub first_frame: u32,
    /// Pre-roll frames of the run (`output.preroll`), and how many of them are done.
    pub preroll: u32,
    pub preroll_done: u32,
    pub rest: Option<RestTracker>,
    pub writer: FrameWriter,
    pub manifest: Manifest,
    pub stats: StatsLog,
    pub layer: LayerWriter,
    pub adapter: String,
    pub sim_hash: String,
}

/// Makes the (locked) run directory ready, before anything else is written: a fresh run's is
/// refused or cleared (`super::run_dir`), a resumed run's temporary files are leftovers of a
/// process that died and go; then the folders are made.
pub(super) fn prepare(run_dir: &RunDir, start: &Start) -> Result<()> {
    match start {
        Start::Fresh { force } => super::survey::prepare_fresh(run_dir.root(), *force)?,
        Start::Resume => {
            crate::io::atomic::remove_temp_files(run_dir.root())?;
        }
    }
    run_dir.create_dirs(true)
}

/// Opens the run of `shot` in `run_dir` (prepared by [`prepare`]) as `opts.start` says.
pub(super) fn open(shot: &Shot, opts: &RunOptions, run_dir: &RunDir) -> Result<Opened> {
    let cfg = shot.config();
    let sim_hash = config::sim_hash(cfg);

    // What to resume from, decided before the GPU is opened (bad input fails fast).
    let resumed = match opts.start {
        Start::Fresh { .. } => None,
        Start::Resume => Some(checkpoint_to_resume(
            cfg,
            &run_dir.checkpoints(),
            &sim_hash,
        )?),
    };

    // Frames simulated before the first written one (`output.preroll`), and how many of them a
    // checkpoint taken during the pre-roll had done.
    let preroll = cfg.output.preroll_frames();
    let preroll_done = match &resumed {
        None => 0,
        Some(ck) => match preroll_progress(ck, preroll)? {
            Some(done) => done,
            None => preroll,
        },
    };

    let ctx = match &opts.device {
        Some(ctx) => ctx.clone(),
        None => Arc::new(gpu::Context::new(&cfg.gpu)?),
    };
    let adapter = ctx.adapter_name();
    let (sim, first_frame) = match &resumed {
        None => (Simulation::new(ctx.clone(), shot)?, cfg.output.frames.start),
        Some(ck) => resume_simulation(ctx, shot, ck, &adapter)?,
    };
    let rest = rest_tracker(cfg, resumed.as_ref())?;

    let writer = FrameWriter::new(shot, cfg, run_dir)?;
    let mut manifest = match (&resumed, Manifest::load(run_dir)) {
        (Some(_), Ok(m)) => m,
        (Some(_), Err(_)) => {
            // Resuming without a manifest: rebuild it from the frame files on disk.
            let mut m = writer.new_manifest(cfg, &adapter, &sim_hash)?;
            let rebuilt = writer.records_on_disk(cfg.output.frames.start, first_frame)?;
            eprintln!(
                "note: {} rebuilt from the files on disk ({} frames found)",
                run_dir.manifest().display(),
                rebuilt.len()
            );
            for rec in rebuilt {
                m.record_frame(rec);
            }
            m
        }
        _ => writer.new_manifest(cfg, &adapter, &sim_hash)?,
    };
    manifest.adapter = adapter.clone();
    manifest.config = serde_json::to_value(cfg).map_err(|e| Error::Runtime(e.to_string()))?;
    manifest.config_hash = config::full_hash(cfg);
    manifest.frame_end = cfg.output.frames.end;
    manifest.complete = false;
    let stats = match resumed {
        Some(_) => StatsLog::load_until(run_dir, first_frame)?,
        None => StatsLog::default(),
    };
    // A resumed run's layer holds what the manifest records (a lost or stale one is re-made).
    let layer = LayerWriter::new(cfg);
    layer.update(run_dir.root(), &mut manifest)?;
    manifest.save(run_dir)?;
    Ok(Opened {
        sim,
        first_frame,
        preroll,
        preroll_done,
        rest,
        writer,
        manifest,
        stats,
        layer,
        adapter,
        sim_hash,
    })
}

/// The simulation of checkpoint `ck` and the first frame it simulates.
fn resume_simulation(
    ctx: Arc<gpu::Context>,
    shot: &Shot,
    ck: &Checkpoint,
    adapter: &str,
) -> Result<(Simulation, u32)> {
    let cfg = shot.config();
    if ck.extra.contains_key(PREROLL_SECTION) {
        // A checkpoint of the pre-roll: no frame is written yet.
        let clock = SimClock {
            frame: cfg.output.frames.start,
            step: ck.header.step,
            time: ck.header.time,
            next_id: ck.header.next_id,
        };
        return Ok((
            Simulation::from_state(ctx, shot, &ck.state, clock)?,
            cfg.output.frames.start,
        ));
    }
    if ck.header.adapter != adapter {
        eprintln!(
            "warning: checkpoint written on adapter '{}', resuming on '{}': frames may differ bit for bit",
            ck.header.adapter, adapter
        );
    }
    // The header holds the last completed frame; the clock counts the next one.
    // Bounded by check_resume_frame: frame <= frames.end <= config::MAX_FRAME.
    let next = ck.header.frame + 1;
    let clock = SimClock {
        frame: next,
        step: ck.header.step,
        time: ck.header.time,
        next_id: ck.header.next_id,
    };
    Ok((Simulation::from_state(ctx, shot, &ck.state, clock)?, next))
}

/// Rest positions (`sim::rest`), on the host, carried in every checkpoint: none unless the run
/// tracks them; empty for a fresh run or a checkpoint of the pre-roll (they start with the
/// first written frame); else the checkpoint's, which must hold them.
fn rest_tracker(
    cfg: &config::ShotConfig,
    resumed: Option<&Checkpoint>,
) -> Result<Option<RestTracker>> {
    if !cfg.export.tracks_rest() {
        return Ok(None);
    }
    let Some(ck) = resumed.filter(|ck| !ck.extra.contains_key(PREROLL_SECTION)) else {
        return Ok(Some(RestTracker::default()));
    };
    match ck.extra.get(rest::CHECKPOINT_SECTION) {
        Some(bytes) => Ok(Some(RestTracker::from_bytes(bytes)?)),
        None => Err(Error::InvalidInput(format!(
            "cannot resume: the checkpoint of frame {} holds no rest positions, and \
             export.detail / export.grids.rest need them; resume with them off, or run \
             again from the start",
            ck.header.frame
        ))),
    }
}
