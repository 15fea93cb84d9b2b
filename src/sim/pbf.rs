//! Position Based Fluids (paper section 3): the parameters (shaders/pbf.wgsl `PbfParams`,
//! byte-identical) and the stage that records prediction, density iterations and velocity update.
use crate::config::ShotConfig;
use crate::error::Result;
use crate::gpu::buffers::ParamSlots;
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{entry_points, Dispatch, Program};
use crate::gpu::Context;
use crate::shot::Shot;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PbfParams {
    pub dt: f32,
    pub inv_dt: f32,
    pub rest_density: f32,
    pub m0: f32,
    pub h0: f32,
    /// Relaxation epsilon of eq. 4 in 1/m^2: `solver.relaxation / h0^2`.
    pub eps: f32,
    pub scorr_k: f32,
    pub scorr_n: f32,
    pub scorr_dq: f32,
    pub xsph: f32,
    pub vorticity: f32,
    pub gravity: f32,
    pub max_speed: f32,
    /// 1: the wall particles' gradient is taken along y alone (`domain.free_slip`).
    pub free_slip: u32,
    /// Under-density up to this fraction of rho0 is not corrected (`solver.expansion_tolerance`).
    pub expansion_tolerance: f32,
    /// The share of that correction split particles get (`solver.split_expansion_weight`).
    pub split_expansion_weight: f32,
    /// Per level l (0..8): (h_l, 315 / (64 pi h_l^9), -45 / (pi h_l^6), m_l).
    pub levels: [[f32; 4]; crate::ground::levels::MAX_LEVEL as usize + 1],
}

impl PbfParams {
    /// The parameters at the shot's fewest substeps (`output.substeps`); [`Self::set_dt`]
    /// changes the substep. h0, m0 and the level table are the shot's.
    pub fn for_shot(shot: &Shot) -> Self {
        let cfg = shot.config();
        let s = &cfg.solver;
        let h0 = shot.h0();
        let dt = cfg.output.substep_dt(cfg.output.substeps);
        let mut p = Self {
            dt: dt as f32,
            inv_dt: (1.0 / dt) as f32,
            rest_density: s.rest_density as f32,
            m0: shot.m0() as f32,
            h0: h0 as f32,
            eps: (s.relaxation / (h0 * h0)) as f32,
            scorr_k: s.scorr_k as f32,
            scorr_n: s.scorr_n as f32,
            scorr_dq: s.scorr_dq as f32,
            xsph: s.xsph as f32,
            vorticity: s.vorticity as f32,
            gravity: s.gravity as f32,
            max_speed: s.max_speed as f32,
            free_slip: cfg.domain.free_slip as u32,
            expansion_tolerance: s.expansion_tolerance as f32,
            split_expansion_weight: s.split_expansion_weight as f32,
            levels: std::array::from_fn(|l| {
                let h = shot.level_radius(l as u32);
                let pi = std::f64::consts::PI;
                [
                    h as f32,
                    (315.0 / (64.0 * pi * h.powi(9))) as f32,
                    (-45.0 / (pi * h.powi(6))) as f32,
                    shot.level_mass(l as u32) as f32,
                ]
            }),
        };
        p.set_dt(cfg, dt);
        p
    }

    /// A substep of `dt` seconds: dt, 1/dt and the XSPH fraction of this substep,
    /// `1 - (1 - solver.xsph)^(dt / solver.reference_step)`, and the s_corr strength
    /// `solver.scorr_k min(dt / solver.reference_step, 1)`.
    pub fn set_dt(&mut self, cfg: &ShotConfig, dt: f64) {
        self.dt = dt as f32;
        self.inv_dt = (1.0 / dt) as f32;
        let share = cfg.solver.step_share(dt);
        self.xsph = crate::sim::smoothing::rate_share(cfg.solver.xsph, share) as f32;
        // s_corr acts in every iteration of every substep, and its pushes add up like a
        // stiffness: at 4x the substeps the same k held a heated layer in place (docs/PHYSICS.md
        // "Substeps"); so k is per reference_step too
        // (never above k itself: a substep longer than reference_step does not push harder)
        self.scorr_k = (cfg.solver.scorr_k * share.min(1.0)) as f32;
    }
}

entry_points! {
    /// The entry points of shaders/pbf.wgsl, in the order of a substep.
    pub enum PbfEntry in "pbf.wgsl" {
        /// v += -g dt, speed clamp, p* = x + v dt (gravity acts here).
        Predict = "predict",
        /// lambda of a substep's first iteration (records the neighbour mask).
        ComputeLambda = "compute_lambda",
        /// lambda of the later iterations (the mask's neighbours).
        ComputeLambdaMasked = "compute_lambda_masked",
        /// The position correction of eq. 4.
        ComputeDelta = "compute_delta",
        /// v = (p* - x) / dt.
        UpdateVelocity = "update_velocity",
        /// Vorticity confinement's curl.
        Vorticity = "vorticity",
        /// XSPH viscosity and the vorticity force.
        ViscosityConfine = "viscosity_confine",
        /// x = p*.
        FinishPositions = "finish_positions",
    }
}

/// The PBF passes of a substep (shaders/pbf.wgsl; f64 mirror `sim::reference::pbf`):
/// prediction, the density iterations and the velocity update, bound once to the particle
/// buffers. The neighbour grid between prediction and solve is [`crate::sim::grid`].
pub struct PbfStage {
    program: Program<PbfEntry>,
    params: ParamSlots<PbfParams>,
    bind: wgpu::BindGroup,
    /// The s_corr exponent the pipelines were compiled with (`SCORR_N` in the WGSL).
    scorr_n: f32,
    /// Whether vorticity confinement is on (`solver.vorticity > 0`, fixed for the shot).
    vorticity: bool,
}

impl PbfStage {
    pub fn new(ctx: &Context, params: &PbfParams, b: &ParticleBuffers) -> Result<Self> {
        let scorr_n = params.scorr_n;
        let constants = [("SCORR_N", scorr_n as f64)];
        let program = Program::with_constants(ctx, &constants)?;
        let vorticity = params.vorticity > 0.0;
        let params = ParamSlots::single(ctx, "pbf params", params);
        let own = [
            ("prm", params.slot(0)),
            ("scratch", b.pairs.as_entire_binding()),
        ];
        let bind = program.bind(ctx, &[&own, b])?;
        Ok(Self {
            program,
            params,
            bind,
            scorr_n,
            vorticity,
        })
    }

    /// New parameters (a new substep length), from the next submit on.
    pub fn set_params(&self, ctx: &Context, params: &PbfParams) {
        debug_assert_eq!(params.scorr_n, self.scorr_n, "SCORR_N is compiled in");
        self.params.write(ctx, 0, params);
    }

    /// Records one entry point over the live particles.
    pub(crate) fn run(&self, pass: &mut wgpu::ComputePass, entry: PbfEntry, live: &LiveBuffer) {
        self.program
            .dispatch(pass, entry, &[(&self.bind, 0)], Dispatch::Live(live));
    }

    /// `iterations` Jacobi iterations of the density constraint (eqs. 1-4). The first
    /// compute_lambda records each particle's neighbours (shaders/pbf.wgsl "Neighbour mask"),
    /// the later passes of the substep visit only those.
    fn solve(&self, pass: &mut wgpu::ComputePass, live: &LiveBuffer, iterations: u32) {
        for it in 0..iterations {
            let lambda = if it == 0 {
                PbfEntry::ComputeLambda
            } else {
                PbfEntry::ComputeLambdaMasked
            };
            self.run(pass, lambda, live);
            self.run(pass, PbfEntry::ComputeDelta, live);
        }
    }

    /// v = (p* - x) / dt and the density into the scratch (the height gained waits in
    /// `density`), vorticity confinement (if on), XSPH (the final v and the height gained into
    /// vel, and the density at p* into `density`), x = p* (w = 0: pos.w held the neighbour
    /// mask's anchor).
    fn update_velocity(&self, pass: &mut wgpu::ComputePass, live: &LiveBuffer) {
        self.run(pass, PbfEntry::UpdateVelocity, live);
        if self.vorticity {
            self.run(pass, PbfEntry::Vorticity, live);
        }
        self.run(pass, PbfEntry::ViscosityConfine, live);
        self.run(pass, PbfEntry::FinishPositions, live);
    }
}

impl Stage for PbfStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        let params = PbfParams::for_shot(setup.shot);
        Self::new(setup.ctx, &params, setup.buffers)
    }

    /// Prediction, the density iterations, or the velocity update; the neighbour grid between
    /// prediction and solve is a stage of its own ([`crate::sim::grid`]).
    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        let live = sub.live;
        match phase {
            Phase::Predict => self.run(&mut rec.pass(), PbfEntry::Predict, live),
            Phase::Solve => self.solve(&mut rec.pass(), live, sub.iterations),
            Phase::Velocity => self.update_velocity(&mut rec.pass(), live),
            other => return Err(crate::sim::stage::not_recorded("PBF", other)),
        }
        Ok(())
    }

    fn device_bytes(&self) -> u64 {
        self.params.size()
    }
}
