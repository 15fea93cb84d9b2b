//! `Simulation`: the device buffers of the particles and the substep that advances them.
//!
//! Per substep (one compute pass per phase, timed under its label):
//! - "pbf": `predict` (gravity, speed clamp, p* = x + v dt, wrap/walls);
//! - "grid": cell keys of p*, stable radix sort of (cell, index), cell table, and every particle
//!   array (x, p*, thermo, info) gathered into cell order;
//! - "pbf": `iterations` x (`compute_lambda`: p* -> (p*, lambda) in the scratch; `compute_delta`:
//!   scratch -> corrected p*), so a neighbour's position and lambda are one load and no pass
//!   copies p* back;
//! - "velocity": `update_velocity`, `vorticity` (if enabled), `viscosity_confine`, x = p*.
//!
//! Between `predict` and `update_velocity` the velocity buffer is dead (PBF recomputes v from
//! the positions), so it serves as the gather target of the permutation; the (key, value) sort
//! arrays and the vec4 scratch share one buffer. That keeps the device at <= 100 bytes/particle.
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::gpu::buffers::{read_back, storage_init, storage_zeroed, uniform_init};
use crate::gpu::kernel::{range, Bind, Kernel};
use crate::gpu::sort::{key_bits, RadixSort};
use crate::gpu::timing::GpuTimer;
use crate::gpu::Context;
use crate::sim::adaptive::{AdaptiveBuffers, AdaptiveStage};
use crate::sim::grid_params::GridParams;
use crate::sim::pbf::PbfParams;
use crate::sim::smoothing::{SmoothingBuffers, SmoothingStage};
use crate::sim::thermo::{LayerBuoyancy, ThermoBuffers, ThermoStage};
use crate::sim::ParticleState;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Where the simulation stands; checkpoints store it next to the particles.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SimClock {
    pub frame: u32,
    pub step: u64,
    pub time: f64,
    pub next_id: u32,
}

/// What one `step_frame` measured.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameReport {
    pub phase_ms: BTreeMap<String, f64>,
    pub diagnostics: BTreeMap<String, f64>,
}

const WG: u32 = 64;

struct Buffers {
    pos: wgpu::Buffer,
    vel: wgpu::Buffer,
    thermo: wgpu::Buffer,
    info: wgpu::Buffer,
    pred: wgpu::Buffer,
    /// 4 u32 arrays of `capacity` for the sort, or one vec4 array of scratch
    pairs: wgpu::Buffer,
    density: wgpu::Buffer,
    cell_start: wgpu::Buffer,
    bpos: wgpu::Buffer,
    bcell_start: wgpu::Buffer,
    grid_u: wgpu::Buffer,
    params_u: wgpu::Buffer,
    count_u: wgpu::Buffer,
}

struct Binds {
    keys: wgpu::BindGroup,
    table: wgpu::BindGroup,
    /// (gather into vel, copy back) for pos, pred, thermo
    perm4: Vec<(wgpu::BindGroup, wgpu::BindGroup)>,
    perm2: (wgpu::BindGroup, wgpu::BindGroup),
    pbf: wgpu::BindGroup,
    scratch_to_vel: wgpu::BindGroup,
    pred_to_pos: wgpu::BindGroup,
}

struct Kernels {
    grid: Kernel,
    perm4: Kernel,
    perm2: Kernel,
    pbf: Kernel,
}

/// Stages a test may run one at a time (`run_stage`), to compare with the CPU mirror.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    Predict,
    Grid,
    Lambda,
    Delta,
    UpdateVelocity,
    Vorticity,
    ViscosityConfine,
    /// the rest of the substep after `ViscosityConfine`: v = scratch, x = p*
    Finish,
}

/// Device buffers a test may read (`read_vec4`, `read_f32`, `read_u32`).
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Buf {
    Pos,
    Vel,
    Pred,
    /// (p*, lambda) after `Stage::Lambda`, the new v after `Stage::ViscosityConfine`
    Scratch,
    Density,
    CellStart,
    Info,
}

pub struct Simulation {
    ctx: Arc<Context>,
    clock: SimClock,
    cfg: ShotConfig,
    /// max over particles of |v| / h (1/s) in the newest state: the CFL control's input
    speed_ratio: f64,
    /// density iterations per substep: `solver.iterations` per `solver.reference_step`
    iterations: u32,
    count: u32,
    capacity: u32,
    n_boundary: u32,
    grid: GridParams,
    params: PbfParams,
    b: Buffers,
    k: Kernels,
    g: Binds,
    sort: RadixSort,
    timer: Option<GpuTimer>,
    boundary_host: (Vec<[f32; 4]>, Vec<u32>),
    smoothing: SmoothingStage,
    thermo: ThermoStage,
    /// Split and merge (paper 5.2); `None` when `adaptive.enabled` is false.
    adaptive: Option<AdaptiveStage>,
}

impl Simulation {
    /// A fresh shot: the initial state of section 5 at `output.frames.start`.
    pub fn new(ctx: Arc<Context>, cfg: &ShotConfig) -> Result<Self> {
        let state = crate::sim::init::initial_particles(cfg);
        let clock = SimClock {
            frame: cfg.output.frames.start,
            step: 0,
            time: 0.0,
            next_id: state.len() as u32,
        };
        Self::from_state(ctx, cfg, &state, clock)
    }

    /// Resumes from a read-back (or checkpointed) state; continues bit-identically.
    pub fn from_state(
        ctx: Arc<Context>,
        cfg: &ShotConfig,
        state: &ParticleState,
        clock: SimClock,
    ) -> Result<Self> {
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
        if cfg.output.substeps == 0
            || cfg.output.frame_seconds.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
        {
            return Err(Error::Config(
                "output.substeps and output.frame_seconds must be positive".into(),
            ));
        }
        let factor = if cfg.adaptive.enabled {
            cfg.adaptive.capacity_factor.max(1.0)
        } else {
            1.0
        };
        let capacity = (((n as f64 * factor).ceil() as u64).max(n as u64)).next_multiple_of(64);
        let limits = ctx.device.limits();
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if capacity * 16 > max_binding || capacity > u32::MAX as u64 / 2 {
            return Err(Error::InvalidInput(format!(
                "{n} particles (capacity {capacity}) exceed the GPU's largest storage buffer ({max_binding} bytes); use a larger spacing"
            )));
        }
        let capacity = capacity as u32;
        let mut grid = GridParams::for_shot(cfg);
        for (per, a, name) in [(grid.periodic_x(), 0, "x"), (grid.periodic_z(), 2, "z")] {
            if per && grid.dims[a] < 3 {
                return Err(Error::Config(format!(
                    "domain.periodic: axis {name} needs at least 3 kernel radii of extent (domain.size / (spacing * kernel_ratio) >= 3)"
                )));
            }
        }
        let (bpos, bcell) = crate::sim::init::boundary_particles(cfg, &grid);
        grid.n_particles = n as u32;
        grid.n_boundary = bpos.len() as u32;
        let mut params = PbfParams::for_shot(cfg);
        params.single_level = state.info.iter().all(|i| i[1] == 0) as u32;
        let dev = &ctx.device;

        let cap = capacity as usize;
        let upload4 = |label: &str, data: &[[f32; 4]]| {
            let buf = storage_zeroed::<[f32; 4]>(dev, label, cap);
            ctx.queue.write_buffer(&buf, 0, bytemuck::cast_slice(data));
            buf
        };
        let info = storage_zeroed::<[u32; 2]>(dev, "info", cap);
        ctx.queue
            .write_buffer(&info, 0, bytemuck::cast_slice(&state.info));
        let density = storage_zeroed::<f32>(dev, "density", cap);
        ctx.queue
            .write_buffer(&density, 0, bytemuck::cast_slice(&state.density));
        let b = Buffers {
            pos: upload4("pos", &state.pos),
            vel: upload4("vel", &state.vel),
            thermo: upload4("thermo", &state.thermo),
            info,
            pred: storage_zeroed::<[f32; 4]>(dev, "pred", cap),
            pairs: storage_zeroed::<[u32; 4]>(dev, "sort pairs / scratch", cap),
            density,
            cell_start: storage_zeroed::<u32>(dev, "cell_start", grid.table_len()),
            bpos: storage_init(dev, "boundary pos", &bpos),
            bcell_start: storage_init(dev, "boundary cell_start", &bcell),
            grid_u: uniform_init(dev, "grid", &grid),
            params_u: uniform_init(dev, "pbf params", &params),
            count_u: uniform_init(dev, "count", &[n as u32, 0, 0, 0]),
        };
        let s4 = Bind::Storage;
        let k = Kernels {
            grid: Kernel::new(
                dev,
                "grid.wgsl",
                &[Bind::Uniform, s4, s4, s4, s4],
                &["cell_keys", "cell_table"],
            )?,
            perm4: Kernel::new(
                dev,
                "permute4.wgsl",
                &[Bind::Uniform, s4, s4, s4],
                &["permute4", "copy4"],
            )?,
            perm2: Kernel::new(
                dev,
                "permute2.wgsl",
                &[Bind::Uniform, s4, s4, s4],
                &["permute2", "copy2"],
            )?,
            pbf: Kernel::new(
                dev,
                "pbf.wgsl",
                &[
                    Bind::Uniform,
                    Bind::Uniform,
                    s4,
                    s4,
                    s4,
                    s4,
                    s4,
                    // info, cell_start, bpos, bcell_start: read-only in every pbf entry point
                    Bind::StorageRead,
                    Bind::StorageRead,
                    Bind::StorageRead,
                    Bind::StorageRead,
                ],
                &[
                    "predict",
                    "compute_lambda",
                    "compute_delta",
                    "update_velocity",
                    "vorticity",
                    "viscosity_confine",
                ],
            )?,
        };
        let bits = key_bits(grid.table_len() as u32 - 2);
        let mut sort = RadixSort::new(dev, &b.pairs, capacity, bits)?;
        sort.set_count(&ctx.queue, n as u32);
        let arr = capacity as u64 * 4;
        let (ko, vo) = sort.result_offsets();
        fn e(x: &wgpu::Buffer) -> wgpu::BindingResource<'_> {
            x.as_entire_binding()
        }
        let p4 = |src: &wgpu::Buffer, dst: &wgpu::Buffer, order: wgpu::BindingResource| {
            k.perm4.bind(dev, &[e(&b.count_u), order, e(src), e(dst)])
        };
        let order = || range(&b.pairs, vo, arr);
        let g = Binds {
            keys: k.grid.bind(
                dev,
                &[
                    e(&b.grid_u),
                    e(&b.pred),
                    range(&b.pairs, 0, arr),
                    range(&b.pairs, arr, arr),
                    e(&b.cell_start),
                ],
            ),
            table: k.grid.bind(
                dev,
                &[
                    e(&b.grid_u),
                    e(&b.pred),
                    range(&b.pairs, ko, arr),
                    order(),
                    e(&b.cell_start),
                ],
            ),
            perm4: [&b.pos, &b.pred, &b.thermo]
                .iter()
                .map(|a| (p4(a, &b.vel, order()), p4(&b.vel, a, order())))
                .collect(),
            perm2: (
                k.perm2
                    .bind(dev, &[e(&b.count_u), order(), e(&b.info), e(&b.vel)]),
                k.perm2
                    .bind(dev, &[e(&b.count_u), order(), e(&b.vel), e(&b.info)]),
            ),
            pbf: k.pbf.bind(
                dev,
                &[
                    e(&b.grid_u),
                    e(&b.params_u),
                    e(&b.pos),
                    e(&b.vel),
                    e(&b.pred),
                    e(&b.pairs),
                    e(&b.density),
                    e(&b.info),
                    e(&b.cell_start),
                    e(&b.bpos),
                    e(&b.bcell_start),
                ],
            ),
            // copies do not read `order`; bind an unrelated buffer there to avoid aliasing
            scratch_to_vel: p4(&b.pairs, &b.vel, e(&b.density)),
            pred_to_pos: p4(&b.pred, &b.pos, e(&b.density)),
        };
        let timer = ctx.timestamps.then(|| GpuTimer::new(dev, &ctx.queue));
        let smoothing = SmoothingStage::new(&ctx, cfg)?;
        let mut thermo = ThermoStage::new(&ctx, cfg)?;
        thermo.set_layers(LayerBuoyancy::of_state(cfg, state));
        let adaptive = if cfg.adaptive.enabled {
            let h0 = cfg.domain.spacing * cfg.domain.kernel_ratio;
            Some(AdaptiveStage::new(
                &ctx,
                &cfg.adaptive,
                &grid,
                h0,
                capacity,
            )?)
        } else {
            None
        };
        Ok(Self {
            smoothing,
            thermo,
            adaptive,
            clock,
            cfg: cfg.clone(),
            speed_ratio: speed_ratio(&state.vel, &state.info, params.h0 as f64),
            iterations: cfg.solver.iterations,
            count: n as u32,
            capacity,
            n_boundary: grid.n_boundary,
            grid,
            params,
            b,
            k,
            g,
            sort,
            timer,
            boundary_host: (bpos, bcell),
            ctx,
        })
    }

    pub fn clock(&self) -> SimClock {
        self.clock
    }
    pub fn capacity(&self) -> usize {
        self.capacity as usize
    }
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
        self.n_boundary as usize
    }
    /// Boundary particles (cell-ordered, w = temperature) and their cell table.
    pub fn boundary(&self) -> (&[[f32; 4]], &[u32]) {
        (&self.boundary_host.0, &self.boundary_host.1)
    }

    /// Bytes of every device buffer this simulation allocated.
    pub fn device_bytes(&self) -> u64 {
        let b = &self.b;
        [
            &b.pos,
            &b.vel,
            &b.thermo,
            &b.info,
            &b.pred,
            &b.pairs,
            &b.density,
            &b.cell_start,
            &b.bpos,
            &b.bcell_start,
            &b.grid_u,
            &b.params_u,
            &b.count_u,
        ]
        .iter()
        .map(|x| x.size())
        .sum::<u64>()
            + self.sort.device_bytes()
    }

    fn threads(&self) -> u32 {
        self.count
    }

    fn encode_predict(&self, pass: &mut wgpu::ComputePass) {
        self.k
            .pbf
            .dispatch(pass, "predict", &self.g.pbf, self.threads(), WG);
    }

    fn encode_grid(&self, pass: &mut wgpu::ComputePass) {
        let n = self.threads();
        let (k, g) = (&self.k, &self.g);
        k.grid.dispatch(pass, "cell_keys", &g.keys, n, WG);
        self.sort.encode(pass);
        k.grid.dispatch(pass, "cell_table", &g.table, n, WG);
        for (gather, back) in &g.perm4 {
            k.perm4.dispatch(pass, "permute4", gather, n, WG);
            k.perm4.dispatch(pass, "copy4", back, n, WG);
        }
        k.perm2.dispatch(pass, "permute2", &g.perm2.0, n, WG);
        k.perm2.dispatch(pass, "copy2", &g.perm2.1, n, WG);
    }

    fn encode_iteration(&self, pass: &mut wgpu::ComputePass) {
        let n = self.threads();
        self.k
            .pbf
            .dispatch(pass, "compute_lambda", &self.g.pbf, n, WG);
        self.k
            .pbf
            .dispatch(pass, "compute_delta", &self.g.pbf, n, WG);
    }

    fn encode_velocity(&self, pass: &mut wgpu::ComputePass) {
        let n = self.threads();
        let pbf = &self.k.pbf;
        pbf.dispatch(pass, "update_velocity", &self.g.pbf, n, WG);
        if self.params.vorticity > 0.0 {
            pbf.dispatch(pass, "vorticity", &self.g.pbf, n, WG);
        }
        pbf.dispatch(pass, "viscosity_confine", &self.g.pbf, n, WG);
        self.encode_finish(pass);
    }

    fn encode_finish(&self, pass: &mut wgpu::ComputePass) {
        let n = self.threads();
        self.k
            .perm4
            .dispatch(pass, "copy4", &self.g.scratch_to_vel, n, WG);
        self.k
            .perm4
            .dispatch(pass, "copy4", &self.g.pred_to_pos, n, WG);
    }

    /// `measure`: after the solve, one more density pass, so that the density the frame reports
    /// is that of the corrected positions.
    fn encode_phase(&self, phase: &str, pass: &mut wgpu::ComputePass, measure: bool) {
        match phase {
            "predict" => self.encode_predict(pass),
            "grid" => self.encode_grid(pass),
            "solve" => {
                for _ in 0..self.iterations {
                    self.encode_iteration(pass);
                }
                if measure {
                    self.k
                        .pbf
                        .dispatch(pass, "compute_lambda", &self.g.pbf, self.threads(), WG);
                }
            }
            _ => self.encode_velocity(pass),
        }
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

    fn wait(&self) -> Result<()> {
        self.ctx
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::Runtime(format!("GPU poll failed: {e}")))
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
            || self.cfg.physics.buoyancy_reference == crate::config::BuoyancyReference::LayerMean;
        // (phase, timing label)
        const PHASES: [(&str, &str); 4] = [
            ("predict", "pbf"),
            ("grid", "grid"),
            ("solve", "pbf"),
            ("velocity", "velocity"),
        ];
        let mut report = FrameReport::default();
        let ctx = self.ctx.clone();
        let dev = &ctx.device;
        let mut last_error = (0.0, 0.0);
        let mut last_compression = (0.0, 0.0);
        let substeps = self.substeps_for_next_frame();
        let dt = self.cfg.output.frame_seconds / substeps as f64;
        self.iterations = iterations_per_substep(&self.cfg, dt);
        if self.params.dt != dt as f32 {
            self.params.set_dt(&self.cfg, dt);
            self.ctx
                .queue
                .write_buffer(&self.b.params_u, 0, bytemuck::bytes_of(&self.params));
        }
        for sub in 0..substeps {
            let last = sub + 1 == substeps;
            if let Some(mut timer) = self.timer.take() {
                let mut enc = dev.create_command_encoder(&Default::default());
                for (phase, label) in PHASES {
                    let mut pass = timer.pass(&mut enc, label);
                    self.encode_phase(phase, &mut pass, last);
                }
                self.ctx.queue.submit([enc.finish()]);
                self.timer = Some(timer);
            } else {
                for (phase, label) in PHASES {
                    let t0 = std::time::Instant::now();
                    let mut enc = dev.create_command_encoder(&Default::default());
                    {
                        let mut pass = enc.begin_compute_pass(&Default::default());
                        self.encode_phase(phase, &mut pass, last);
                    }
                    self.ctx.queue.submit([enc.finish()]);
                    self.wait()?;
                    *report.phase_ms.entry(label.to_string()).or_insert(0.0) +=
                        t0.elapsed().as_secs_f64() * 1e3;
                }
            }
            if self.timer.is_some() {
                // The CPU-timed phases below must not include the PBF work still queued.
                self.wait()?;
            }
            self.cloud_physics(&mut report)?;
            self.clock.step += 1;
            self.clock.time += self.params.dt as f64;
            if last {
                // Read before split/merge, which move particles without their densities.
                let density: Vec<f32> =
                    read_back(dev, &self.ctx.queue, &self.b.density, self.count as usize)?;
                let rho0 = self.params.rest_density as f64;
                last_error = density_error(&density, rho0);
                last_compression = compression_error(&density, rho0);
            }
            self.adapt(&mut report)?;
        }
        if let Some(timer) = self.timer.as_mut() {
            let mut enc = dev.create_command_encoder(&Default::default());
            timer.resolve(&mut enc);
            self.ctx.queue.submit([enc.finish()]);
            report.phase_ms.extend(timer.collect(dev)?);
        }
        self.clock.frame += 1;
        let end = if full {
            self.state()?
        } else {
            let (n, q) = (self.count as usize, &self.ctx.queue);
            ParticleState {
                vel: read_back(dev, q, &self.b.vel, n)?,
                info: read_back(dev, q, &self.b.info, n)?,
                ..Default::default()
            }
        };
        self.speed_ratio = speed_ratio(&end.vel, &end.info, self.params.h0 as f64);
        self.thermo
            .set_layers(LayerBuoyancy::of_state(&self.cfg, &end));
        report
            .diagnostics
            .insert("substeps".into(), substeps as f64);
        report
            .diagnostics
            .insert("cfl_max".into(), self.speed_ratio * dt);
        let (mean, max) = last_error;
        report.diagnostics.insert("density_error_mean".into(), mean);
        report.diagnostics.insert("density_error_max".into(), max);
        let (mean, max) = last_compression;
        report
            .diagnostics
            .insert("density_compression_mean".into(), mean);
        report
            .diagnostics
            .insert("density_compression_max".into(), max);
        report
            .diagnostics
            .insert("particles".into(), self.count as f64);
        if self.adaptive.is_some() {
            self.level_diagnostics(&mut report, &end.info);
        }
        Ok((report, end))
    }

    /// Temperature smoothing (4.1), then heating, buoyancy, cooling, phase transition and latent
    /// heat (eqs. 5-11), in the paper's order after the PBF move. The particles are in the cell
    /// order of the grid just built, so the smoothing reads valid neighbourhoods.
    fn cloud_physics(&mut self, report: &mut FrameReport) -> Result<()> {
        let b = &self.b;
        let t0 = std::time::Instant::now();
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        self.smoothing.encode(
            &mut enc,
            &SmoothingBuffers {
                grid: &b.grid_u,
                pos: &b.pos,
                info: &b.info,
                thermo: &b.thermo,
                cell_start: &b.cell_start,
                boundary: &b.bpos,
                boundary_cell_start: &b.bcell_start,
            },
            self.count,
            self.params.dt as f64,
        );
        self.ctx.queue.submit([enc.finish()]);
        self.wait()?;
        let t1 = std::time::Instant::now();
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        self.thermo.encode(
            &mut enc,
            &ThermoBuffers {
                pos: &b.pos,
                vel: &b.vel,
                thermo: &b.thermo,
            },
            self.count,
            self.params.dt as f64,
            self.clock.time,
        );
        self.ctx.queue.submit([enc.finish()]);
        self.wait()?;
        let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64() * 1e3;
        *report.phase_ms.entry("smoothing".into()).or_insert(0.0) += ms(t0, t1);
        *report.phase_ms.entry("cloud".into()).or_insert(0.0) += ms(t1, std::time::Instant::now());
        Ok(())
    }

    /// Shape energy, split and merge at the end of the substep (5.2); the count may change.
    fn adapt(&mut self, report: &mut FrameReport) -> Result<()> {
        let Some(stage) = &self.adaptive else {
            return Ok(());
        };
        let b = &self.b;
        let r = stage.run(
            &self.ctx,
            &AdaptiveBuffers {
                grid: &b.grid_u,
                pos: &b.pos,
                vel: &b.vel,
                thermo: &b.thermo,
                info: &b.info,
                cell_start: &b.cell_start,
            },
            self.count,
            self.clock.next_id,
        )?;
        self.clock.next_id = r.next_id;
        *report.phase_ms.entry("split".into()).or_insert(0.0) += r.phase_ms.split;
        *report.phase_ms.entry("merge".into()).or_insert(0.0) += r.phase_ms.merge;
        for (key, v) in [
            ("splits", r.splits),
            ("merges", r.merges),
            ("skipped_splits", r.skipped_splits),
        ] {
            *report.diagnostics.entry(key.into()).or_insert(0.0) += v as f64;
        }
        self.set_count(r.count);
        if r.splits > 0 {
            self.set_single_level(false);
        }
        Ok(())
    }

    /// Switches the PBF pair terms between the level-0 fast path and the per-level kernels.
    /// Splits switch it off at once; only the per-frame level count switches it back on, so the
    /// choice is a function of the state at frame boundaries (resume takes it from the state).
    fn set_single_level(&mut self, single: bool) {
        if (self.params.single_level != 0) == single {
            return;
        }
        self.params.single_level = single as u32;
        self.ctx
            .queue
            .write_buffer(&self.b.params_u, 0, bytemuck::bytes_of(&self.params));
    }

    /// Tells every stage how many particles are live.
    fn set_count(&mut self, n: u32) {
        if n == self.count {
            return;
        }
        self.count = n;
        self.grid.n_particles = n;
        self.ctx
            .queue
            .write_buffer(&self.b.grid_u, 0, bytemuck::bytes_of(&self.grid));
        self.ctx
            .queue
            .write_buffer(&self.b.count_u, 0, bytemuck::cast_slice(&[n, 0u32, 0, 0]));
        self.sort.set_count(&self.ctx.queue, n);
    }

    /// Particles per level and total mass in units of m0 2^-max_level (exact integers).
    fn level_diagnostics(&mut self, report: &mut FrameReport, info: &[[u32; 2]]) {
        let Some(stage) = &self.adaptive else {
            return;
        };
        let max_level = stage.max_level();
        let mut per_level = vec![0u64; max_level as usize + 1];
        let mut units = 0u64;
        for &[_, level] in info {
            per_level[(level.min(max_level)) as usize] += 1;
            units += crate::sim::adaptive::level_mass_units(level, max_level);
        }
        for (l, n) in per_level.iter().enumerate() {
            report
                .diagnostics
                .insert(format!("particles_level_{l}"), *n as f64);
        }
        report.diagnostics.insert("mass_units".into(), units as f64);
        self.set_single_level(per_level.iter().skip(1).all(|&n| n == 0));
    }

    /// Blocking read-back of the live particles (in the device's current cell order).
    pub fn state(&self) -> Result<ParticleState> {
        let (dev, q, n) = (&self.ctx.device, &self.ctx.queue, self.count as usize);
        Ok(ParticleState {
            pos: read_back(dev, q, &self.b.pos, n)?,
            vel: read_back(dev, q, &self.b.vel, n)?,
            thermo: read_back(dev, q, &self.b.thermo, n)?,
            info: read_back(dev, q, &self.b.info, n)?,
            density: read_back(dev, q, &self.b.density, n)?,
        })
    }

    /// Runs one stage alone (tests compare it with the CPU mirror).
    #[doc(hidden)]
    pub fn run_stage(&mut self, stage: Stage) -> Result<()> {
        let mut enc = self.ctx.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            let (n, pbf, bg) = (self.threads(), &self.k.pbf, &self.g.pbf);
            match stage {
                Stage::Predict => self.encode_predict(&mut pass),
                Stage::Grid => self.encode_grid(&mut pass),
                Stage::Lambda => pbf.dispatch(&mut pass, "compute_lambda", bg, n, WG),
                Stage::Delta => pbf.dispatch(&mut pass, "compute_delta", bg, n, WG),
                Stage::UpdateVelocity => pbf.dispatch(&mut pass, "update_velocity", bg, n, WG),
                Stage::Vorticity => pbf.dispatch(&mut pass, "vorticity", bg, n, WG),
                Stage::ViscosityConfine => pbf.dispatch(&mut pass, "viscosity_confine", bg, n, WG),
                Stage::Finish => self.encode_finish(&mut pass),
            }
        }
        self.ctx.queue.submit([enc.finish()]);
        self.wait()
    }

    fn buffer(&self, which: Buf) -> &wgpu::Buffer {
        match which {
            Buf::Pos => &self.b.pos,
            Buf::Vel => &self.b.vel,
            Buf::Pred => &self.b.pred,
            Buf::Scratch => &self.b.pairs,
            Buf::Density => &self.b.density,
            Buf::CellStart => &self.b.cell_start,
            Buf::Info => &self.b.info,
        }
    }

    #[doc(hidden)]
    pub fn read_vec4(&self, which: Buf) -> Result<Vec<[f32; 4]>> {
        read_back(
            &self.ctx.device,
            &self.ctx.queue,
            self.buffer(which),
            self.count as usize,
        )
    }
    #[doc(hidden)]
    pub fn read_f32(&self, which: Buf) -> Result<Vec<f32>> {
        read_back(
            &self.ctx.device,
            &self.ctx.queue,
            self.buffer(which),
            self.count as usize,
        )
    }
    #[doc(hidden)]
    pub fn read_u32(&self, which: Buf, len: usize) -> Result<Vec<u32>> {
        read_back(&self.ctx.device, &self.ctx.queue, self.buffer(which), len)
    }
    /// Overwrites the first entries of a buffer (tests seed fresh random inputs this way).
    #[doc(hidden)]
    pub fn write<T: bytemuck::Pod>(&self, which: Buf, data: &[T]) {
        self.ctx
            .queue
            .write_buffer(self.buffer(which), 0, bytemuck::cast_slice(data));
    }
}

/// Density iterations of a substep of dt: `solver.iterations` per `solver.reference_step`
/// (at least 1, at most `solver.iterations`). Each Jacobi projection also takes a share of the
/// buoyant motion, so a fixed count per substep made more substeps a stiffer, slower air
/// (quickstart at 8 substeps x 8 iterations: 17 t of cloud at frame 48 against 96 t at 2).
pub fn iterations_per_substep(cfg: &ShotConfig, dt: f64) -> u32 {
    let share = (dt / cfg.solver.reference_step).min(1.0);
    ((cfg.solver.iterations as f64 * share).round() as u32).max(1)
}

/// max over particles of |v_i| / h_i (1/s), h_i = h0 2^(-l/3): times dt, the largest
/// displacement per substep in kernel radii.
pub fn speed_ratio(vel: &[[f32; 4]], info: &[[u32; 2]], h0: f64) -> f64 {
    vel.iter()
        .zip(info)
        .map(|(v, i)| {
            let s = (v[0] as f64).hypot(v[1] as f64).hypot(v[2] as f64);
            s / (h0 * (-(i[1] as f64) / 3.0).exp2())
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
