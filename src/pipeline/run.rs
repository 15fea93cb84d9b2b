//! The frame loop: the GPU simulates frame N+1 while a writer thread splats and writes frame N
//! (a bounded queue of one frame keeps memory bounded). Checkpoints are written after the writer
//! has caught up, so every frame up to a checkpoint is on disk before the checkpoint exists.
use super::checkpoints::{write_checkpoint, PrerollMark};
use super::lock::{Create, RunLock};
use super::naming::resume_command;
use super::open::{RunOptions, Start};
use super::progress::{LogFormat, Progress};
use super::records::{FrameStats, Manifest, StatsLog};
use super::run_dir::RunDir;
use super::writer::{FrameJob, FrameWriter, WrittenFrame};
use crate::config::{self, ShotConfig};
use crate::error::{Error, Result};
use crate::gpu;
use crate::ground::ParticleState;
use crate::shot::Shot;
use crate::sim::rest::{self, RestTracker};
use crate::sim::Simulation;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::Arc;
use std::time::Instant;

/// `nimbus run CONFIG`: a new run of `shot` into `out_dir` (created if missing; refused when it
/// holds an earlier run, unless `force`: see `run_dir`). Resuming is `super::resume`.
pub fn run_fresh(shot: &Shot, out_dir: &Path, log: LogFormat, force: bool) -> Result<()> {
    let cfg = shot.config();
    // What can be checked of --out without writing comes first (exit 2, with or without a
    // GPU); then the device, and whether it holds the shot: a shot it cannot hold is refused
    // (exit 4, the limit and the largest particle count that fits) before anything is written.
    super::survey::check_fresh_out(out_dir, force)?;
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

/// Runs (or resumes) a shot into `opts.out_dir`, which `lock` must hold: opens it
/// (`super::open`), starts the writer thread, steps the pre-roll and the written frames, and
/// completes the records.
pub fn run(shot: &Shot, opts: &RunOptions, lock: &RunLock) -> Result<()> {
    let cfg = shot.config();
    let run_dir = RunDir::new(&opts.out_dir);
    if lock.dir() != run_dir.root() {
        return Err(Error::Runtime(format!(
            "internal: {} is run without its lock",
            run_dir.root().display()
        )));
    }
    // Checked before anything is written (a refused run leaves the directory as it was).
    super::open::prepare(&run_dir, &opts.start)?;
    let interrupted = install_signal_handlers()?;
    let opened = super::open::open(shot, opts, &run_dir)?;

    let (start, end) = (cfg.output.frames.start, cfg.output.frames.end);
    let progress = Progress::new(opts.log, start, end, opened.first_frame);
    progress.note(
        "start",
        &format!(
            "nimbus {}: shot '{}' frames {}..={end} on {}",
            crate::VERSION,
            cfg.shot,
            opened.first_frame,
            opened.adapter
        ),
    );
    let writer = Arc::new(opened.writer);
    let thread = WriterThread::spawn(writer.clone())?;
    let mut frames = FrameLoop {
        cfg,
        run_dir: &run_dir,
        progress: &progress,
        interrupted: &interrupted,
        writer: &writer,
        sim: opened.sim,
        rest: opened.rest,
        adapter: opened.adapter,
        sim_hash: opened.sim_hash,
        records: Records {
            in_flight: 0,
            layer: opened.layer,
            manifest: opened.manifest,
            stats: opened.stats,
            pending_stats: Vec::new(),
        },
    };
    let result = frames
        .preroll(opened.preroll_done, opened.preroll)
        .and_then(|()| frames.written_frames(opened.first_frame, &thread));
    let mut records = frames.records;
    let drained = thread.finish(&mut records, &run_dir, &progress);
    progress.finish();
    result?;
    drained?;
    records.manifest.complete = true;
    records
        .layer
        .update(run_dir.root(), &mut records.manifest)?;
    records.manifest.save(&run_dir)?;
    writer.finish_run(&records.manifest)?;
    progress.note(
        "done",
        &format!(
            "done: {} frames in {}",
            end - start + 1,
            run_dir.root().display()
        ),
    );
    Ok(())
}

/// The writer thread: splat + write + preview, one frame at a time, in order, fed through a
/// queue of one frame.
struct WriterThread {
    jobs: SyncSender<FrameJob>,
    done: Receiver<Result<WrittenFrame>>,
    handle: std::thread::JoinHandle<()>,
}

impl WriterThread {
    fn spawn(writer: Arc<FrameWriter>) -> Result<Self> {
        let (jobs, job_rx) = sync_channel::<FrameJob>(1);
        let (done_tx, done) = std::sync::mpsc::channel::<Result<WrittenFrame>>();
        let handle = std::thread::Builder::new()
            .name("nimbus-writer".into())
            .spawn(move || {
                for job in job_rx {
                    if done_tx.send(writer.write(job)).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| Error::Runtime(format!("cannot start the writer thread: {e}")))?;
        Ok(Self { jobs, done, handle })
    }

    fn send(&self, job: FrameJob) -> Result<()> {
        self.jobs
            .send(job)
            .map_err(|_| Error::Runtime("the writer thread stopped unexpectedly".into()))
    }

    /// Closes the queue, records the frames still with the writer and ends the thread.
    fn finish(self, records: &mut Records, run_dir: &RunDir, progress: &Progress) -> Result<()> {
        drop(self.jobs);
        let drained = records.collect(&self.done, run_dir, progress, true);
        let _ = self.handle.join();
        drained
    }
}

/// The frame loop's state: the simulation, what it needs to checkpoint, and the records.
struct FrameLoop<'a> {
    cfg: &'a ShotConfig,
    run_dir: &'a RunDir,
    progress: &'a Progress,
    /// Set by SIGINT/SIGTERM/SIGHUP: finish the frame, checkpoint and stop.
    interrupted: &'a AtomicBool,
    writer: &'a FrameWriter,
    sim: Simulation,
    rest: Option<RestTracker>,
    adapter: String,
    sim_hash: String,
    records: Records,
}

impl FrameLoop<'_> {
    /// The pre-roll frames `done..frames`: simulated, checked and checkpointed (every
    /// `checkpoint.every` and when interrupted), never written.
    fn preroll(&mut self, done: u32, frames: u32) -> Result<()> {
        let cfg = self.cfg;
        let start = cfg.output.frames.start;
        if done < frames {
            self.progress.note(
                "preroll",
                &format!(
                    "pre-roll: {} of {frames} frames ({} s of simulated time) before frame {start}",
                    frames - done,
                    frames as f64 * cfg.output.frame_seconds,
                ),
            );
        }
        for done in done..frames {
            self.progress.phase(start, "pre-roll", 0);
            let (_, state) = self.sim.step_frame_with_state()?;
            if let Some(what) = super::watchdog::check(&state, cfg) {
                return Err(Error::Runtime(format!(
                    "simulation diverged in pre-roll frame {} of {frames}: {what}",
                    done + 1
                )));
            }
            let stop = self.interrupted.load(Ordering::SeqCst);
            let due = cfg.checkpoint.every > 0 && (done + 1).is_multiple_of(cfg.checkpoint.every);
            if due || stop {
                let mark = PrerollMark {
                    done: done + 1,
                    frames,
                };
                let path = self.checkpoint(&state, Some(mark), false, start)?;
                self.progress.note(
                    "checkpoint",
                    &format!(
                        "checkpoint {} (pre-roll frame {} of {frames})",
                        path.display(),
                        done + 1
                    ),
                );
            }
            if stop {
                return Err(Error::Interrupted(format!(
                    "stopped in pre-roll frame {} of {frames}; resume with: {}",
                    done + 1,
                    resume_command(self.run_dir.root())
                )));
            }
        }
        Ok(())
    }

    /// The written frames `first..=frames.end`: each simulated, checked, its stats taken and
    /// handed to the writer; a checkpoint (after the writer caught up) every
    /// `checkpoint.every` frames, at the end and when interrupted.
    fn written_frames(&mut self, first: u32, thread: &WriterThread) -> Result<()> {
        let cfg = self.cfg;
        let (start, end) = (cfg.output.frames.start, cfg.output.frames.end);
        let rest_clock = rest::rest_clock(cfg);
        let rest_codec = crate::ground::rest::RestCodec::new(
            cfg.domain.size,
            [
                cfg.domain.periodic.contains(&config::Axis::X),
                cfg.domain.periodic.contains(&config::Axis::Z),
            ],
        );
        let h0 = cfg.domain.kernel_radius();
        let initial_layers = crate::sim::diagnostics::initial_layer_mass(cfg);
        for frame in first..=end {
            let t0 = Instant::now();
            self.progress.phase(frame, "simulate", 0);
            let (report, mut state) = self.sim.step_frame_with_state()?;
            crate::fault::during_frame(frame);
            crate::fault::poison_state(frame, &mut state);
            // Before the frame is written or checkpointed: a diverged state reaches no file.
            if let Some(what) = super::watchdog::check(&state, cfg) {
                return Err(Error::Runtime(format!(
                    "simulation diverged at frame {frame}: {what}; frames before it and the \
                     last good checkpoint are kept"
                )));
            }
            let frame_rest = self
                .rest
                .as_mut()
                .map(|t| Arc::new(t.update(&state, frame, &rest_clock, &rest_codec, h0)));
            let state = Arc::new(state);
            let clock = self.sim.clock();
            let cloud = crate::sim::diagnostics::cloud_diagnostics(&state, cfg);
            let atmosphere = crate::sim::diagnostics::atmosphere_diagnostics(
                &state,
                cfg,
                &initial_layers,
                clock.time,
                self.sim.heat_maps(),
            );
            let clamped = atmosphere.clamped_particles;
            if let Some(msg) = time_step_warning(frame, &report.diagnostics, clamped, cfg) {
                self.progress.note("warning", &msg);
            }
            self.records.pending_stats.push(FrameStats {
                frame,
                sim_time: clock.time,
                particles: state.len() as u64,
                phases: report.phases,
                writer: Default::default(),
                step: report.diagnostics,
                cloud,
                atmosphere,
            });
            let skip_write = self.records.manifest.frame(frame).is_some_and(|rec| {
                self.writer.has_all_files(rec)
                    && super::records::frame_intact(self.run_dir.root(), rec)
            });
            self.progress
                .phase(frame, "splat + write", state.len() as u64);
            thread.send(FrameJob {
                frame,
                state: state.clone(),
                skip_write,
                started: t0,
                rest: frame_rest,
            })?;
            self.records.in_flight += 1;
            self.records
                .collect(&thread.done, self.run_dir, self.progress, false)?;

            let stop = self.interrupted.load(Ordering::SeqCst);
            let due = cfg.checkpoint.every > 0
                && (frame - start + 1).is_multiple_of(cfg.checkpoint.every);
            if due || stop || frame == end {
                self.records
                    .collect(&thread.done, self.run_dir, self.progress, true)?;
                let path = self.checkpoint(&state, None, true, frame)?;
                self.progress
                    .note("checkpoint", &format!("checkpoint {}", path.display()));
            }
            if stop && frame < end {
                return Err(Error::Interrupted(format!(
                    "stopped after frame {frame}; resume with: {}",
                    resume_command(self.run_dir.root())
                )));
            }
        }
        Ok(())
    }

    /// A checkpoint of `state` as frame `frame` (with the rest positions when `with_rest`).
    fn checkpoint(
        &self,
        state: &ParticleState,
        preroll: Option<PrerollMark>,
        with_rest: bool,
        frame: u32,
    ) -> Result<PathBuf> {
        write_checkpoint(
            self.cfg,
            &self.run_dir.checkpoints(),
            &self.sim_hash,
            &self.adapter,
            state,
            preroll,
            self.rest.as_ref().filter(|_| with_rest),
            frame,
            &self.sim,
        )
    }
}

/// The run's records as the frames come back from the writer.
struct Records {
    in_flight: usize,
    /// The USD layer, rewritten with the manifest's new frames.
    layer: super::usd_layer::LayerWriter,
    manifest: Manifest,
    stats: StatsLog,
    /// Stats of frames still with the writer: a stats line lands with its frame's files.
    pending_stats: Vec<FrameStats>,
}

impl Records {
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
                s.writer = done.phase_ms;
                self.stats.push(&s);
            }
            self.layer.update(run_dir.root(), &mut self.manifest)?;
            self.manifest.save(run_dir)?;
            self.stats.save(run_dir)?;
            progress.frame_done(done.frame, done.particles, done.wall_ms);
        }
        Ok(())
    }
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
