//! `Simulation`: the particle set on the device, its stages, and the frame loop that records the
//! substeps (the stages and the order of one substep are in `sim/step.rs`) and reads the state
//! back once.
//!
//! A frame records its substeps without waiting for the GPU: one submit per substep, the count
//! that split and merge change stays on the GPU (`gpu::live`), and the host reads the state,
//! the counters and the phase timestamps back at the frame's end: one wait per frame, two with
//! adaptivity (the live count first, then exactly that many particles). stats.jsonl records the
//! waits (`host_waits`).
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::gpu::buffers::Readback;
use crate::gpu::live::Live;
use crate::gpu::timing::GpuTimer;
use crate::gpu::Context;
use crate::ground::{ParticleState, SimClock};
use crate::shot::Shot;
use crate::sim::adaptive::{self, AdaptiveStage};
use crate::sim::buffers::ParticleBuffers;
use crate::sim::control::Target;
use crate::sim::frame_report::{FrameReport, Levels, SplitMerge};
use crate::sim::grid_params::GridParams;
use crate::sim::pbf::PbfParams;
use crate::sim::phase::{Phase, PhaseTimes, Recorder, Timing};
use crate::sim::sources::HeatMaps;
use crate::sim::stage::{Setup, Stage};
use crate::sim::step::Stages;
use crate::sim::thermo::LayerBuoyancy;
use std::sync::Arc;

pub struct Simulation {
    pub(super) ctx: Arc<Context>,
    pub(super) clock: SimClock,
    pub(super) cfg: ShotConfig,
    /// max over particles of |v| / h (1/s) in the newest state: the CFL control's input
    speed_ratio: f64,
    /// density iterations of the substep being recorded ([`iterations_in_substep`])
    pub(super) iterations: u32,
    /// live particles as of the last read-back (the GPU's `live.count` between frames)
    count: u32,
    grid: GridParams,
    pub(super) params: PbfParams,
    pub(super) b: ParticleBuffers,
    pub(super) s: Stages,
    timer: Option<GpuTimer<Phase>>,
    timing: Timing,
    boundary_host: (Vec<[f32; 4]>, Vec<u32>),
    /// `control.target`, voxelised (`sim::control`): its supply map is set from every frame's
    /// read-back state, and `target_iou` measured, also when its control is off.
    target: Option<Target>,
}

impl Simulation {
    /// A fresh shot: the initial state of section 5 at `output.frames.start`.
    pub fn new(ctx: Arc<Context>, shot: &Shot) -> Result<Self> {
        let cfg = shot.config();
        let state = crate::sim::init::initial_particles(cfg);
        let clock = SimClock {
            frame: cfg.output.frames.start,
            step: 0,
            time: 0.0,
            next_id: state.len() as u32,
        };
        Self::from_state(ctx, shot, &state, clock)
    }

    /// Resumes from a read-back (or checkpointed) state; continues bit-identically.
    pub fn from_state(
        ctx: Arc<Context>,
        shot: &Shot,
        state: &ParticleState,
        clock: SimClock,
    ) -> Result<Self> {
        let cfg = shot.config();
        let n = state.len();
        if n == 0 {
            return Err(Error::InvalidInput(
                "the shot has no particles (domain smaller than the spacing?)".into(),
            ));
        }
        if state.vel.len() != n
            || state.thermo.len() != n
            || state.info.len() != n
            || state.density.len() != n
        {
            return Err(Error::InvalidInput(
                "particle state arrays have different lengths".into(),
            ));
        }
        // the device holds the shot, or it is refused before anything is allocated (exit 4,
        // with the limit and the largest count that fits; `run` checked it already)
        let target = Target::of_shot(shot);
        let maps = HeatMaps::new(shot.heat_maps()).with_target(target.as_ref());
        let size =
            crate::sim::footprint::ShotSize::with_maps(cfg, n as u64, maps.values.len() as u64);
        let capacity = size.capacity();
        if capacity > u32::MAX as u64 / 2 {
            return Err(Error::InvalidInput(format!(
                "{n} particles (capacity {capacity}): more than nimbus's u32 particle indices hold"
            )));
        }
        crate::sim::footprint::check(&ctx, &size, || None)?;
        let capacity = capacity as u32;
        // (a prepared shot has 3 or more kernel radii along each periodic axis)
        let mut grid = GridParams::for_shot(cfg);
        let boundary = crate::sim::init::boundary_particles(cfg, &grid);
        grid.n_boundary = boundary.0.len() as u32;
        let params = PbfParams::for_shot(shot);
        let b = ParticleBuffers::new(&ctx, state, capacity, &grid, &boundary, clock.next_id)?;
        let mut s = Stages::new(&Setup {
            ctx: &ctx,
            shot,
            buffers: &b,
            grid: &grid,
            maps: &maps,
        })?;
        s.thermo.set_layers(LayerBuoyancy::of_state(cfg, state));
        if s.forces.reads_state() {
            s.forces.start_frame(state);
        }
        // the controller's state is a function of the particles: a resume from a checkpoint
        // sets the same supply as the uninterrupted run did at that frame's end
        if let Some(t) = &target {
            s.thermo.set_supply(&ctx, &t.update(state).0);
        }
        let timer = ctx
            .timestamps
            .then(|| GpuTimer::new(&ctx.device, &ctx.queue));
        Ok(Self {
            clock,
            cfg: cfg.clone(),
            speed_ratio: speed_ratio(&state.vel, &state.info, params.h0 as f64),
            iterations: cfg.solver.iterations,
            count: n as u32,
            grid,
            params,
            b,
            s,
            timer,
            timing: Timing::Timestamps,
            boundary_host: boundary,
            target,
            ctx,
        })
    }

    pub fn clock(&self) -> SimClock {
        self.clock
    }
    /// The heat maps the thermo stage samples (with the controller's current supply map).
    pub fn heat_maps(&self) -> &crate::sim::sources::HeatMaps {
        self.s.thermo.maps()
    }

    /// The voxelised `control.target`, if the shot has one.
    pub fn target(&self) -> Option<&Target> {
        self.target.as_ref()
    }

    pub fn capacity(&self) -> usize {
        self.b.capacity as usize
    }
    /// Live particles at the end of the last frame.
    pub fn count(&self) -> usize {
        self.count as usize
    }
    pub fn grid(&self) -> &GridParams {
        &self.grid
    }
    pub fn params(&self) -> &PbfParams {
        &self.params
    }
    pub fn boundary_count(&self) -> usize {
        self.boundary_host.0.len()
    }
    /// Boundary particles (cell-ordered, w = temperature) and their cell table.
    pub fn boundary(&self) -> (&[[f32; 4]], &[u32]) {
        (&self.boundary_host.0, &self.boundary_host.1)
    }

    /// How frames time their phases: GPU timestamps (the default; untimed without them) or
    /// a wait after every phase (benchmarks on adapters without timestamps).
    pub fn set_timing(&mut self, timing: Timing) {
        self.timing = timing;
    }

    /// Bytes of every device buffer this simulation and its stages allocated (the frame's
    /// read-back staging, host memory that lives for one wait, not counted).
    pub fn device_bytes(&self) -> u64 {
        self.b.device_bytes()
            + self.timer.as_ref().map_or(0, |t| t.buffer().size())
            + self.s.device_bytes()
    }

    /// Substeps for the next frame: the fewest (`output.substeps`) or as many as keep the
    /// largest displacement per substep at `output.cfl` kernel radii, at most
    /// `output.max_substeps`. A function of the state alone, so a resumed run takes the same.
    pub fn substeps_for_next_frame(&self) -> u32 {
        let o = &self.cfg.output;
        let need = (self.speed_ratio * o.frame_seconds / o.cfl).ceil();
        let need = if need.is_finite() {
            need.min(u32::MAX as f64) as u32
        } else {
            u32::MAX
        };
        need.clamp(o.substeps, o.max_substeps.max(o.substeps))
    }

    /// Advances one frame: [`Self::substeps_for_next_frame`] substeps of dt = frame_seconds /
    /// substeps.
    pub fn step_frame(&mut self) -> Result<FrameReport> {
        Ok(self.advance_frame(false)?.0)
    }

    /// [`Self::step_frame`], returning the state at the frame's end as well: one read-back
    /// serves the time-step control, the diagnostics and the caller (the run loop writes it).
    pub fn step_frame_with_state(&mut self) -> Result<(FrameReport, ParticleState)> {
        self.advance_frame(true)
    }

    /// One frame; at its end reads the whole state (`full`) or only what the time-step control
    /// and the level counts need (vel, info).
    fn advance_frame(&mut self, full: bool) -> Result<(FrameReport, ParticleState)> {
        // the next frame's buoyancy profile needs positions and thermo
        let full = full
            || self.cfg.physics.buoyancy_reference == crate::config::BuoyancyReference::LayerMean
            || self.target.is_some()
            || self.s.forces.reads_state();
        let ctx = self.ctx.clone();
        let waits_before = ctx.waits();
        let mut report = FrameReport::default();
        let substeps = self.substeps_for_next_frame();
        let dt = self.cfg.output.substep_dt(substeps);
        if self.params.dt != dt as f32 {
            self.params.set_dt(&self.cfg, dt);
            self.s.pbf.set_params(&ctx, &self.params);
        }
        if let Some(a) = &self.s.adaptive {
            a.start_frame(&ctx);
        }
        let host_timing = self.timing == Timing::HostWaits;
        let mut host_times = PhaseTimes::default();
        let mut timer = self.timer.take();
        for k in 0..substeps {
            self.iterations = iterations_in_substep(&self.cfg, substeps, k);
            let mut rec =
                Recorder::new(&ctx, timer.as_mut(), host_timing.then_some(&mut host_times));
            let recorded = self.record_substep(&mut rec, dt, k == 0);
            rec.submit();
            if let Err(e) = recorded {
                self.timer = timer;
                return Err(e);
            }
            self.clock.step += 1;
            self.clock.time += self.params.dt as f64;
        }
        self.timer = timer;
        let (live, end, density, timestamps, counters) = self.read_frame(full)?;
        if let Some(timer) = self.timer.as_mut() {
            for (phase, ms) in timer.spans(&timestamps) {
                report.phases.add(phase, ms);
            }
        }
        report.phases.merge(&host_times);
        if let Some((counters, load)) = &counters {
            let budget = self
                .s
                .adaptive
                .as_ref()
                .map_or(u32::MAX, |a| a.loop_budget());
            adaptive::load_error(load, budget)?;
            let totals = AdaptiveStage::frame_totals(counters);
            report.diagnostics.split_merge = Some(SplitMerge {
                splits: totals.splits,
                merges: totals.merges,
                skipped_splits: totals.skipped_splits,
            });
        }
        self.count = live.count;
        self.clock.next_id = live.next_id;
        self.clock.frame += 1;
        self.speed_ratio = speed_ratio(&end.vel, &end.info, self.params.h0 as f64);
        self.s
            .thermo
            .set_layers(LayerBuoyancy::of_state(&self.cfg, &end));
        if self.s.forces.reads_state() {
            self.s.forces.frame_figures(&mut report.diagnostics.forces);
            self.s.forces.start_frame(&end);
        }
        if let Some(t) = &self.target {
            let (supply, iou) = t.update(&end);
            self.s.thermo.set_supply(&ctx, &supply);
            report.diagnostics.target_iou = Some(iou);
        }
        let rho0 = self.params.rest_density as f64;
        let d = &mut report.diagnostics;
        d.substeps = substeps;
        d.cfl_max = self.speed_ratio * dt;
        (d.density_error_mean, d.density_error_max) = density_error(&density, rho0);
        (d.density_compression_mean, d.density_compression_max) = compression_error(&density, rho0);
        d.particles = self.count;
        let single_level = if self.s.adaptive.is_some() {
            self.level_diagnostics(&mut report, &end.info)
        } else {
            live.single_level != 0
        };
        // The live state the next frame starts from, as the host now knows it; the single-level
        // flag comes back on only here, so the choice is a function of the frame-start state.
        let next = Live::new(&ctx, live.count, live.next_id, single_level);
        if next != live {
            self.b.live.write(&ctx, &next);
        }
        report.diagnostics.host_waits = ctx.waits() - waits_before;
        Ok((report, end))
    }

    /// The frame's one read-back (two with adaptivity: the live count first): the live state,
    /// the particles (all arrays with `full`, else vel and info), the densities of the last
    /// solve, the phase timestamps and the adaptive counters with the merge load.
    #[allow(clippy::type_complexity)]
    fn read_frame(
        &mut self,
        full: bool,
    ) -> Result<(
        Live,
        ParticleState,
        Vec<f32>,
        Vec<u64>,
        Option<(Vec<u32>, Vec<u32>)>,
    )> {
        let ctx = self.ctx.clone();
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let ts_bytes = self.timer.as_ref().map_or(0, |t| t.resolve(&mut enc));
        let mut rb = Readback::default();
        let live_k = rb.add_array::<Live>(self.b.live.buffer(), 1);
        let ts_k = self.timer.as_ref().map(|t| rb.add(t.buffer(), 0, ts_bytes));
        let adaptive_k = self.s.adaptive.as_ref().map(|a| {
            (
                rb.add(a.counters(), 0, a.counters().size()),
                rb.add(a.load(), 0, a.load().size()),
            )
        });
        // Without adaptivity the count is known: the particles come in the same read-back.
        let known = self.s.adaptive.is_none().then_some(self.count as usize);
        let mut state_parts = known.map(|n| self.add_state(&mut rb, n, n, full));
        let data = rb.finish(&ctx, enc)?;
        let live: Live = data.get::<Live>(live_k)[0];
        let timestamps = ts_k.map(|k| data.get::<u64>(k)).unwrap_or_default();
        let counters = adaptive_k.map(|(c, l)| (data.get::<u32>(c), data.get::<u32>(l)));
        if live.count as usize > self.capacity() || live.solved_count as usize > self.capacity() {
            return Err(Error::Runtime(format!(
                "the GPU reports {} live particles, more than the capacity {}",
                live.count,
                self.capacity()
            )));
        }
        let data = match state_parts.take() {
            Some(parts) => (data, parts),
            None => {
                let mut rb = Readback::default();
                let parts = self.add_state(
                    &mut rb,
                    live.count as usize,
                    live.solved_count as usize,
                    full,
                );
                let enc = ctx.device.create_command_encoder(&Default::default());
                (rb.finish(&ctx, enc)?, parts)
            }
        };
        let (data, parts) = data;
        let n = live.count as usize;
        let mut density: Vec<f32> = data.get(parts.density);
        let solved = density[..live.solved_count as usize].to_vec();
        density.truncate(n);
        let get4 = |k: Option<usize>| k.map(|k| data.get::<[f32; 4]>(k)).unwrap_or_default();
        let end = ParticleState {
            pos: get4(parts.pos),
            vel: data.get(parts.vel),
            thermo: get4(parts.thermo),
            info: data.get(parts.info),
            density: if full { density } else { Vec::new() },
        };
        Ok((live, end, solved, timestamps, counters))
    }

    /// Adds the particle arrays (`n` live, densities of `solved` particles) to a read-back.
    fn add_state<'a>(
        &'a self,
        rb: &mut Readback<'a>,
        n: usize,
        solved: usize,
        full: bool,
    ) -> StateParts {
        let b = &self.b;
        StateParts {
            pos: full.then(|| rb.add_array::<[f32; 4]>(&b.pos, n)),
            vel: rb.add_array::<[f32; 4]>(&b.vel, n),
            thermo: full.then(|| rb.add_array::<[f32; 4]>(&b.thermo, n)),
            info: rb.add_array::<[u32; 2]>(&b.info, n),
            density: rb.add_array::<f32>(&b.density, n.max(solved)),
        }
    }

    /// Particles per level and total mass in units of m0 2^-max_level (exact integers); returns
    /// whether every particle is on level 0.
    fn level_diagnostics(&self, report: &mut FrameReport, info: &[[u32; 2]]) -> bool {
        let Some(stage) = &self.s.adaptive else {
            return true;
        };
        let max_level = stage.max_level();
        let mut per_level = vec![0u64; max_level as usize + 1];
        let mut units = 0u64;
        for &[_, level] in info {
            per_level[(level.min(max_level)) as usize] += 1;
            units += crate::sim::adaptive::level_mass_units(level, max_level);
        }
        let single_level = per_level.iter().skip(1).all(|&n| n == 0);
        report.diagnostics.levels = Some(Levels {
            per_level,
            mass_units: units,
        });
        single_level
    }

    /// Read-back of the live particles (in the device's current cell order); one wait (two
    /// with adaptivity, which must learn the count first).
    pub fn state(&self) -> Result<ParticleState> {
        let ctx = &self.ctx;
        let n = match &self.s.adaptive {
            None => self.count,
            Some(_) => {
                crate::gpu::buffers::read_back::<Live>(ctx, self.b.live.buffer(), 1)?[0].count
            }
        } as usize;
        let mut rb = Readback::default();
        let parts = self.add_state(&mut rb, n, n, true);
        let data = rb.finish(ctx, ctx.device.create_command_encoder(&Default::default()))?;
        let mut density: Vec<f32> = data.get(parts.density);
        density.truncate(n);
        Ok(ParticleState {
            pos: parts.pos.map(|k| data.get(k)).unwrap_or_default(),
            vel: data.get(parts.vel),
            thermo: parts.thermo.map(|k| data.get(k)).unwrap_or_default(),
            info: data.get(parts.info),
            density,
        })
    }
}

/// Where the particle arrays sit in a read-back.
struct StateParts {
    pos: Option<usize>,
    vel: usize,
    thermo: Option<usize>,
    info: usize,
    density: usize,
}

/// Density iterations of a substep of dt: `solver.iterations` per `solver.reference_step`
/// (at least `solver.min_iterations`, at most `solver.iterations`). Each Jacobi projection
/// also takes a share of the buoyant motion, so a fixed count per substep made more substeps a
/// stiffer, slower air (quickstart at 8 substeps x 8 iterations: 17 t of cloud at frame 48
/// against 96 t at 2).
pub fn iterations_per_substep(cfg: &ShotConfig, dt: f64) -> u32 {
    let share = cfg.solver.step_share(dt).min(1.0);
    ((cfg.solver.iterations as f64 * share).round() as u32).max(fewest_iterations(cfg))
}

/// The fewest density iterations a substep runs: `solver.min_iterations`, never 0.
fn fewest_iterations(cfg: &ShotConfig) -> u32 {
    cfg.solver.min_iterations.max(1)
}

/// Density iterations of substep k of a frame of `substeps`: [`iterations_per_substep`], or
/// with `solver.spread_iterations` the frame's round(iterations frame_seconds /
/// reference_step) spread evenly (the cumulative count rounded at each substep's end), at
/// least `solver.min_iterations` a substep. Rounding each substep's share makes the rate jump
/// with the substep count the CFL control takes (at 4 per 15 s: 10 substeps of a minute run
/// 20, 11 run 11); a function of the frame's substep count alone, so a resumed run takes the
/// same.
pub fn iterations_in_substep(cfg: &ShotConfig, substeps: u32, k: u32) -> u32 {
    if !cfg.solver.spread_iterations {
        return iterations_per_substep(cfg, cfg.output.substep_dt(substeps));
    }
    let total = cfg.solver.iterations as f64 * cfg.solver.step_share(cfg.output.frame_seconds);
    let done_by = |j: u32| (total * j as f64 / substeps as f64).round() as u64;
    ((done_by(k + 1) - done_by(k)) as u32).max(fewest_iterations(cfg))
}

/// max over particles of |v_i| / h_i (1/s), h_i = h0 2^(-l/3): times dt, the largest
/// displacement per substep in kernel radii.
pub fn speed_ratio(vel: &[[f32; 4]], info: &[[u32; 2]], h0: f64) -> f64 {
    vel.iter()
        .zip(info)
        .map(|(v, i)| {
            let s = (v[0] as f64).hypot(v[1] as f64).hypot(v[2] as f64);
            s / crate::ground::levels::radius(h0, i[1])
        })
        .fold(0.0, f64::max)
}

/// Mean and max of max(rho / rho0 - 1, 0), the over-density alone: the part every particle's
/// constraint corrects (split particles correct nothing else).
pub fn compression_error(density: &[f32], rho0: f64) -> (f64, f64) {
    let over: Vec<f32> = density.iter().map(|&d| d.max(rho0 as f32)).collect();
    density_error(&over, rho0)
}

/// Mean and max of |rho / rho0 - 1| (summed in f64 in index order: deterministic).
pub fn density_error(density: &[f32], rho0: f64) -> (f64, f64) {
    if density.is_empty() {
        return (0.0, 0.0);
    }
    let mut sum = 0.0;
    let mut max: f64 = 0.0;
    for &d in density {
        let e = (d as f64 / rho0 - 1.0).abs();
        sum += e;
        max = max.max(e);
    }
    (sum / density.len() as f64, max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// BOMEX's rates: a minute's frame, 4 iterations per 15 s.
    fn minute_frames(spread: bool) -> ShotConfig {
        let mut cfg: ShotConfig = serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}, frame_seconds: 60}\n\
             domain: {size: [800.0, 800.0, 800.0], spacing: 50.0}\n\
             solver: {iterations: 4, reference_step: 15}\n",
        )
        .unwrap();
        cfg.solver.spread_iterations = spread;
        cfg
    }

    fn frame(cfg: &ShotConfig, substeps: u32) -> Vec<u32> {
        (0..substeps)
            .map(|k| iterations_in_substep(cfg, substeps, k))
            .collect()
    }

    #[test]
    fn spread_iterations_keep_the_rate_at_every_substep_count() {
        let cfg = minute_frames(true);
        for n in 1..=16 {
            let its = frame(&cfg, n);
            assert_eq!(its.iter().sum::<u32>(), 16, "{n} substeps: {its:?}");
            let (lo, hi) = (its.iter().min().unwrap(), its.iter().max().unwrap());
            assert!(hi - lo <= 1, "{n} substeps spread unevenly: {its:?}");
        }
        // beyond 16 substeps a minute every substep still corrects its density once
        assert_eq!(frame(&cfg, 23), vec![1; 23]);
    }

    #[test]
    fn min_iterations_hold_in_short_substeps_alone() {
        for spread in [false, true] {
            let mut cfg = minute_frames(spread);
            let before: Vec<Vec<u32>> = (1..=40).map(|n| frame(&cfg, n)).collect();
            cfg.solver.min_iterations = 2;
            for n in 1..=40u32 {
                let (was, now) = (&before[n as usize - 1], frame(&cfg, n));
                // a substep that ran 2 or more runs the same; one that ran 1 runs 2
                let want: Vec<u32> = was.iter().map(|&i| i.max(2)).collect();
                assert_eq!(now, want, "spread {spread}, {n} substeps");
            }
            assert_eq!(frame(&cfg, 23), vec![2; 23]);
        }
    }

    #[test]
    fn rounded_iterations_are_unchanged_and_jump_with_the_substeps() {
        let cfg = minute_frames(false);
        // each substep rounds its own share, at most `iterations`: what earlier shots ran
        assert_eq!(frame(&cfg, 2), vec![4; 2]);
        assert_eq!(frame(&cfg, 10), vec![2; 10]);
        assert_eq!(frame(&cfg, 11), vec![1; 11]);
        for n in 1..=40 {
            let dt = cfg.output.substep_dt(n);
            assert_eq!(
                frame(&cfg, n),
                vec![iterations_per_substep(&cfg, dt); n as usize]
            );
        }
    }
}
