//! The frame loop: the GPU simulates frame N+1 while a writer thread splats and writes frame N
//! (a bounded queue of one frame keeps memory bounded). Checkpoints are written after the writer
//! has caught up, so every frame up to a checkpoint is on disk before the checkpoint exists.
use super::lock::{Create, RunLock};
use super::naming::resume_command;
use super::progress::{LogFormat, Progress};
use super::records::{FrameStats, Manifest, StatsLog};
use super::run_dir::RunDir;
use super::writer::{FrameJob, FrameWriter, WrittenFrame};
use crate::config::{self, ShotConfig};
use crate::error::{Error, Result};
use crate::gpu;
use crate::ground::{ParticleState, SimClock};
use crate::io::checkpoint;
use crate::shot::Shot;
use crate::sim::rest::{self, RestTracker};
use crate::sim::Simulation;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::Arc;
use std::time::Instant;

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

/// `nimbus run CONFIG`: a new run of `shot` into `out_dir` (created if missing; refused when it
/// holds an earlier run, unless `force`: see `run_dir`). Resuming is `super::resume`.
pub fn run_fresh(shot: &Shot, out_dir: &Path, log: LogFormat, force: bool) -> Result<()> {
    let cfg = shot.config();
    // What can be checked of --out without writing comes first (exit 2, with or without a
    // GPU); then the device, and whether it holds the shot: a shot it cannot hold is refused
    // (exit 4, the limit and the largest particle count that fits) before anything is written.
    super::run_dir::check_fresh_out(out_dir, force)?;
    let ctx = Arc::new(gpu::Context::new(&cfg.gpu)?);
    crate::sim::footprint::check_shot(&ctx, shot, shot.particles())?;
    let lock = RunLock::acquire(out_dir, Create::IfMissing, "run")?;
    let opts = RunOptions {
        out_dir: out_dir.to_path_buf(),
        log,
        start: Start::Fresh { force },
        device: Some(ctx),
    };
    run(shot, &opts, &lock)
}

/// Runs (or resumes) a shot into `opts.out_dir`, which `lock` must hold.
pub fn run(shot: &Shot, opts: &RunOptions, lock: &RunLock) -> Result<()> {
    let cfg = shot.config();
    let run_dir = opts.out_dir.as_path();
    if lock.dir() != run_dir {
        return Err(Error::Runtime(format!(
            "internal: {} is run without its lock",
            run_dir.display()
        )));
    }
    // Checked before anything is written (a refused run leaves the directory as it was).
    match opts.start {
        Start::Fresh { force } => super::run_dir::prepare_fresh(run_dir, force)?,
        // Under the lock every temporary file is a leftover of a process that died.
        Start::Resume => {
            crate::io::atomic::remove_temp_files(run_dir)?;
        }
    }
    let run = RunDir::new(run_dir);
    run.create_dirs(true)?;
    let interrupted = install_signal_handlers()?;
    let sim_hash = config::sim_hash(cfg);
    let ckpt_dir = run.checkpoints();

    // What to resume from, decided before the GPU is opened (bad input fails fast).
    let resumed = match opts.start {
        Start::Fresh { .. } => None,
        Start::Resume => Some(super::resume::checkpoint_to_resume(
            cfg, &ckpt_dir, &sim_hash,
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
    let in_preroll = preroll_done < preroll;

    let ctx = match &opts.device {
        Some(ctx) => ctx.clone(),
        None => Arc::new(gpu::Context::new(&cfg.gpu)?),
    };
    let adapter = ctx.adapter_name();
    let (mut sim, first_frame) = match &resumed {
        None => (Simulation::new(ctx.clone(), shot)?, cfg.output.frames.start),
        Some(ck) if ck.extra.contains_key(PREROLL_SECTION) => {
            // A checkpoint of the pre-roll: no frame is written yet.
            let clock = SimClock {
                frame: cfg.output.frames.start,
                step: ck.header.step,
                time: ck.header.time,
                next_id: ck.header.next_id,
            };
            (
                Simulation::from_state(ctx.clone(), shot, &ck.state, clock)?,
                cfg.output.frames.start,
            )
        }
        Some(ck) => {
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
            (
                Simulation::from_state(ctx.clone(), shot, &ck.state, clock)?,
                next,
            )
        }
    };

    // Rest positions (`sim::rest`), on the host, carried in every checkpoint.
    let mut rest = match (&resumed, cfg.export.tracks_rest()) {
        (_, false) => None,
        (None, true) => Some(RestTracker::default()),
        // the rest positions start with the first written frame
        (Some(ck), true) if ck.extra.contains_key(PREROLL_SECTION) => Some(RestTracker::default()),
        (Some(ck), true) => match ck.extra.get(rest::CHECKPOINT_SECTION) {
            Some(bytes) => Some(RestTracker::from_bytes(bytes)?),
            None => {
                return Err(Error::InvalidInput(format!(
                    "cannot resume: the checkpoint of frame {} holds no rest positions, and \
                     export.detail / export.grids.rest need them; resume with them off, or run \
                     again from the start",
                    ck.header.frame
                )))
            }
        },
    };
    let rest_clock = rest::rest_clock(cfg);
    let rest_codec = crate::ground::rest::RestCodec::new(
        cfg.domain.size,
        [
            cfg.domain.periodic.contains(&config::Axis::X),
            cfg.domain.periodic.contains(&config::Axis::Z),
        ],
    );
    let h0 = cfg.domain.kernel_radius();

    let writer = FrameWriter::new(cfg, shot.heat_maps(), &run)?;
    let mut manifest = match (&resumed, Manifest::load(&run)) {
        (Some(_), Ok(m)) => m,
        (Some(_), Err(_)) => {
            // Resuming without a manifest: rebuild it from the frame files on disk.
            let mut m = writer.new_manifest(cfg, &adapter, &sim_hash)?;
            let rebuilt = writer.records_on_disk(cfg.output.frames.start, first_frame)?;
            eprintln!(
                "note: {} rebuilt from the files on disk ({} frames found)",
                run.manifest().display(),
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
        Some(_) => StatsLog::load_until(&run, first_frame)?,
        None => StatsLog::default(),
    };
    // A resumed run's layer holds what the manifest records (a lost or stale one is re-made).
    let layer = super::usd_layer::LayerWriter::new(cfg);
    layer.update(run_dir, &mut manifest)?;
    manifest.save(&run)?;

    let end = cfg.output.frames.end;
    let progress = Progress::new(opts.log, cfg.output.frames.start, end, first_frame);
    progress.note(
        "start",
        &format!(
            "nimbus {}: shot '{}' frames {first_frame}..={end} on {adapter}",
            crate::VERSION,
            cfg.shot
        ),
    );

    // The writer thread: splat + write + preview, one frame at a time, in order.
    let (job_tx, job_rx) = sync_channel::<FrameJob>(1);
    let (done_tx, done_rx) = std::sync::mpsc::channel::<Result<WrittenFrame>>();
    let writer = Arc::new(writer);
    let worker = {
        let writer = writer.clone();
        std::thread::Builder::new()
            .name("nimbus-writer".into())
            .spawn(move || {
                for job in job_rx {
                    if done_tx.send(writer.write(job)).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| Error::Runtime(format!("cannot start the writer thread: {e}")))?
    };

    let mut loop_state = LoopState {
        in_flight: 0,
        layer,
        manifest,
        stats,
        pending_stats: Vec::new(),
    };
    let initial_layers = crate::sim::diagnostics::initial_layer_mass(cfg);
    let result = (|| -> Result<()> {
        if in_preroll {
            progress.note(
                "preroll",
                &format!(
                    "pre-roll: {} of {preroll} frames ({} s of simulated time) before frame {}",
                    preroll - preroll_done,
                    preroll as f64 * cfg.output.frame_seconds,
                    cfg.output.frames.start
                ),
            );
        }
        for done in preroll_done..preroll {
            progress.phase(cfg.output.frames.start, "pre-roll", 0);
            let (_, state) = sim.step_frame_with_state()?;
            if let Some(what) = super::watchdog::check(&state, cfg) {
                return Err(Error::Runtime(format!(
                    "simulation diverged in pre-roll frame {} of {preroll}: {what}",
                    done + 1
                )));
            }
            let stop = interrupted.load(Ordering::SeqCst);
            let due = cfg.checkpoint.every > 0 && (done + 1).is_multiple_of(cfg.checkpoint.every);
            if due || stop {
                let path = write_checkpoint(
                    cfg,
                    &ckpt_dir,
                    &sim_hash,
                    &adapter,
                    &state,
                    Some(PrerollMark {
                        done: done + 1,
                        frames: preroll,
                    }),
                    None,
                    cfg.output.frames.start,
                    &sim,
                )?;
                progress.note(
                    "checkpoint",
                    &format!(
                        "checkpoint {} (pre-roll frame {} of {preroll})",
                        path.display(),
                        done + 1
                    ),
                );
            }
            if stop {
                return Err(Error::Interrupted(format!(
                    "stopped in pre-roll frame {} of {preroll}; resume with: {}",
                    done + 1,
                    resume_command(run_dir)
                )));
            }
        }
        for frame in first_frame..=end {
            let t0 = Instant::now();
            progress.phase(frame, "simulate", 0);
            let (report, mut state) = sim.step_frame_with_state()?;
            crate::fault::during_frame(frame);
            crate::fault::poison_state(frame, &mut state);
            // Before the frame is written or checkpointed: a diverged state reaches no file.
            if let Some(what) = super::watchdog::check(&state, cfg) {
                return Err(Error::Runtime(format!(
                    "simulation diverged at frame {frame}: {what}; frames before it and the \
                     last good checkpoint are kept"
                )));
            }
            let frame_rest = rest
                .as_mut()
                .map(|t| Arc::new(t.update(&state, frame, &rest_clock, &rest_codec, h0)));
            let state = Arc::new(state);
            let clock = sim.clock();
            let cloud = crate::sim::diagnostics::cloud_diagnostics(&state, cfg);
            let atmosphere = crate::sim::diagnostics::atmosphere_diagnostics(
                &state,
                cfg,
                &initial_layers,
                clock.time,
                sim.heat_maps(),
            );
            let mut diagnostics = report.diagnostics.to_map();
            cloud.insert_into(&mut diagnostics);
            atmosphere.insert_into(&mut diagnostics);
            let clamped = atmosphere.clamped_particles;
            if let Some(msg) = time_step_warning(frame, &report.diagnostics, clamped, cfg) {
                progress.note("warning", &msg);
            }
            loop_state.pending_stats.push(FrameStats {
                frame,
                sim_time: clock.time,
                particles: state.len() as u64,
                phase_ms: report.phases.by_key(),
                diagnostics,
            });
            let skip_write = loop_state.manifest.frame(frame).is_some_and(|rec| {
                writer.has_all_files(rec) && super::records::frame_intact(run_dir, rec)
            });
            progress.phase(frame, "splat + write", state.len() as u64);
            send(
                &job_tx,
                FrameJob {
                    frame,
                    state: state.clone(),
                    skip_write,
                    started: t0,
                    rest: frame_rest,
                },
            )?;
            loop_state.in_flight += 1;
            loop_state.collect(&done_rx, &run, &progress, false)?;

            let stop = interrupted.load(Ordering::SeqCst);
            let due = cfg.checkpoint.every > 0
                && (frame - cfg.output.frames.start + 1).is_multiple_of(cfg.checkpoint.every);
            if due || stop || frame == end {
                loop_state.collect(&done_rx, &run, &progress, true)?;
                let path = write_checkpoint(
                    cfg,
                    &ckpt_dir,
                    &sim_hash,
                    &adapter,
                    &state,
                    None,
                    rest.as_ref(),
                    frame,
                    &sim,
                )?;
                progress.note("checkpoint", &format!("checkpoint {}", path.display()));
            }
            if stop && frame < end {
                return Err(Error::Interrupted(format!(
                    "stopped after frame {frame}; resume with: {}",
                    resume_command(run_dir)
                )));
            }
        }
        Ok(())
    })();
    drop(job_tx);
    let drained = loop_state.collect(&done_rx, &run, &progress, true);
    let _ = worker.join();
    progress.finish();
    result?;
    drained?;
    loop_state.manifest.complete = true;
    loop_state.layer.update(run_dir, &mut loop_state.manifest)?;
    loop_state.manifest.save(&run)?;
    writer.finish_run(&loop_state.manifest)?;
    progress.note(
        "done",
        &format!(
            "done: {} frames in {}",
            end - cfg.output.frames.start + 1,
            run_dir.display()
        ),
    );
    Ok(())
}

struct LoopState {
    in_flight: usize,
    /// The USD layer, rewritten with the manifest's new frames.
    layer: super::usd_layer::LayerWriter,
    manifest: Manifest,
    stats: StatsLog,
    /// Stats of frames still with the writer: a stats line lands with its frame's files.
    pending_stats: Vec<FrameStats>,
}

impl LoopState {
    /// Records finished frames; with `wait`, blocks until the writer has caught up.
    fn collect(
        &mut self,
        rx: &Receiver<Result<WrittenFrame>>,
        run_dir: &RunDir,
        progress: &Progress,
        wait: bool,
    ) -> Result<()> {
        while self.in_flight > 0 {
            let next = if wait {
                rx.recv().ok()
            } else {
                rx.try_recv().ok()
            };
            let Some(done) = next else { break };
            self.in_flight -= 1;
            let done = done?;
            if let Some(rec) = done.record {
                self.manifest.record_frame(rec);
            }
            if let Some(i) = self
                .pending_stats
                .iter()
                .position(|s| s.frame == done.frame)
            {
                let mut s = self.pending_stats.remove(i);
                s.phase_ms.extend(done.phase_ms);
                self.stats.push(s);
            }
            self.layer.update(run_dir.root(), &mut self.manifest)?;
            self.manifest.save(run_dir)?;
            self.stats.save(run_dir)?;
            progress.frame_done(done.frame, done.particles, done.wall_ms);
        }
        Ok(())
    }
}

fn send(tx: &SyncSender<FrameJob>, job: FrameJob) -> Result<()> {
    tx.send(job)
        .map_err(|_| Error::Runtime("the writer thread stopped unexpectedly".into()))
}

/// Checkpoint section of a checkpoint taken during the pre-roll: JSON `{"done": k, "frames":
/// P}`, k of the P pre-roll frames simulated. Such a checkpoint is named after (and its header
/// holds) `frames.start`, the frame the run writes first; the real checkpoint of that frame
/// replaces it.
pub const PREROLL_SECTION: &str = "preroll";

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
struct PrerollMark {
    done: u32,
    frames: u32,
}

/// How many pre-roll frames `ck` had simulated (`None`: it is a checkpoint of a written frame,
/// after the pre-roll). A checkpoint of another pre-roll length cannot be resumed (the sim hash
/// already refuses it; this names why).
fn preroll_progress(ck: &checkpoint::Checkpoint, preroll: u32) -> Result<Option<u32>> {
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
fn write_checkpoint(
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
    let ck = checkpoint::Checkpoint {
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
    checkpoint::write_and_prune(dir, &ck, cfg.checkpoint.keep.max(1) as usize)
}

/// SIGINT/SIGTERM/SIGHUP set a flag: the loop finishes the frame, checkpoints and exits 130.
/// A second signal ends the process at once.
fn install_signal_handlers() -> Result<Arc<AtomicBool>> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let flag = Arc::new(AtomicBool::new(false));
    for sig in [SIGINT, SIGTERM, SIGHUP] {
        signal_hook::flag::register_conditional_shutdown(sig, 130, flag.clone())
            .and_then(|_| signal_hook::flag::register(sig, flag.clone()))
            .map_err(|e| Error::Runtime(format!("cannot install signal handlers: {e}")))?;
    }
    Ok(flag)
}

/// The speed clamp firing, or a frame that needed more substeps than `output.max_substeps`, is
/// never silent: one warning line for the frame.
fn time_step_warning(
    frame: u32,
    d: &crate::sim::StepDiagnostics,
    clamped: u64,
    cfg: &ShotConfig,
) -> Option<String> {
    let cfl = d.cfl_max;
    let mut parts = Vec::new();
    if clamped > 0 {
        parts.push(format!(
            "{clamped:.0} particles at the speed clamp solver.max_speed = {} m/s",
            cfg.solver.max_speed
        ));
    }
    // the CFL control chose the substeps from the frame's start; at the cap it cannot follow
    if d.substeps >= cfg.output.max_substeps && cfl > cfg.output.cfl {
        parts.push(format!(
            "particles moved {cfl:.2} kernel radii per substep (output.cfl {}): raise output.max_substeps ({})",
            cfg.output.cfl, cfg.output.max_substeps
        ));
    }
    (!parts.is_empty()).then(|| format!("warning: frame {frame}: {}", parts.join("; ")))
}
