//! Temperature smoothing as a constraint (paper section 4.1, eqs. 12-17); see
//! docs/PHYSICS.md for what it does and how the isolation diagnostic measures it.
//!
//! One Jacobi iteration (shaders/smoothing.wgsl, entry `smooth_temperature`; f64 mirror
//! `sim::reference::smoothing::smooth_temperature`) reads the temperatures and writes the
//! smoothed ones into a scratch buffer owned by the stage, which is then copied back into
//! `thermo`; `physics.smoothing.iterations` such iterations run per substep, none when
//! `physics.smoothing.enabled` is false and `physics.smoothing.vapor_diffusivity` is 0 (the same
//! pass mixes vapor between neighbours, at cloud edges or, with `physics.smoothing.vapor_mixing:
//! everywhere`, between every pair; docs/PHYSICS.md "The substep, in order" and "BOMEX"). Neighbours come from
//! the cell table (27 cells, minimum-image displacement); with `physics.smoothing.walls: fixed` the boundary particles take
//! part with their fixed temperature, by default (insulated) they are left out.
//!
//! Usage: `let stage = SmoothingStage::new(&ctx, &cfg, &buffers)?;` once, then per substep
//! `stage.smooth(&mut recorder, &live, dt)`.
use crate::config::ShotConfig;
use crate::error::Result;
use crate::gpu::buffers::ParamSlots;
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{entry_points, Dispatch, Program};
use crate::gpu::Context;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};

entry_points! {
    /// The entry points of shaders/smoothing.wgsl, in the order of an iteration.
    pub enum SmoothingEntry in "smoothing.wgsl" {
        /// The vapor-mixing limiter (only with vapor mixing on).
        VaporLimit = "vapor_limit",
        /// k_i of the conservative form (only with `physics.smoothing.conservative`).
        Factor = "smooth_factor",
        /// One Jacobi iteration of eqs. 12-17 and the vapor mixing.
        SmoothTemperature = "smooth_temperature",
    }
}

/// Uniform of shaders/smoothing.wgsl (same layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SmoothParams {
    /// Gamma_d (K/m) with the conservative form, which smooths T + Gamma_d y; 0 otherwise
    /// (the particle count is `live.count`, on the GPU).
    pub lapse: f32,
    /// Level-0 kernel radius h0 (m); level l has h0 2^(-l/3).
    pub h0: f32,
    /// kappa of eq. 17b for one iteration: the share of the configured rate (see `new`).
    pub kappa: f32,
    /// epsilon of eq. 13 (m^2).
    pub epsilon: f32,
    /// Level-0 particle volume m0 / rho0 = spacing^3 (m^3); level l has volume0 2^-l.
    pub volume0: f32,
    /// 1: the walls hold their temperature; 0: insulated walls (no heat crosses them).
    pub fixed_walls: u32,
    /// 2 D dt / iterations (m^2): one iteration's explicit step of vapor mixing with
    /// diffusivity D = `physics.smoothing.vapor_diffusivity` (0 = off).
    pub vapor_rate: f32,
    /// 1: the conservative (pair-flux) form of eq. 17b (`physics.smoothing.conservative`).
    pub conservative: u32,
    /// 1: vapor mixes between every pair of fluid neighbours; 0: only where one of the pair
    /// holds cloud water (`physics.smoothing.vapor_mixing`).
    pub mix_everywhere: u32,
    pub _pad: [u32; 3],
}

impl SmoothParams {
    /// Parameters of one iteration in a substep of `dt` seconds: `physics.smoothing.kappa` is
    /// the fraction applied per `solver.reference_step` seconds, so an iteration applies
    /// `1 - (1 - kappa)^(dt / (reference_step iterations))` and a frame smooths as much at 2
    /// substeps as at 8 (docs/PHYSICS.md "Substeps").
    pub fn new(cfg: &ShotConfig, dt: f64) -> Self {
        let s = &cfg.physics.smoothing;
        let iterations = s.iterations as f64;
        let share = dt / (cfg.solver.reference_step * iterations);
        Self {
            lapse: if s.conservative {
                cfg.physics.adiabatic_lapse_rate as f32
            } else {
                0.0
            },
            h0: cfg.domain.kernel_radius() as f32,
            // Temperature smoothing off while vapor mixing is on: the pass runs for the vapor.
            kappa: if s.enabled {
                rate_share(s.kappa, share) as f32
            } else {
                0.0
            },
            epsilon: s.epsilon as f32,
            volume0: cfg.domain.spacing.powi(3) as f32,
            fixed_walls: (s.walls == crate::config::WallHeat::Fixed) as u32,
            vapor_rate: (2.0 * s.vapor_diffusivity * dt / iterations) as f32,
            conservative: s.conservative as u32,
            mix_everywhere: (s.vapor_mixing == crate::config::VaporMixing::Everywhere) as u32,
            _pad: [0; 3],
        }
    }
}

/// The smoothing pass, bound once to the particle buffers. Its scratch is borrowed from arrays
/// dead after the PBF substep: the smoothed thermo goes to `pairs` and is copied back, the
/// vapor-mixing limiter lives in a quarter of `pred` and the conservative form's k_i in
/// another. It allocates nothing per particle.
pub struct SmoothingStage {
    program: Program<SmoothingEntry>,
    params: ParamSlots<SmoothParams>,
    bind: wgpu::BindGroup,
    cfg: ShotConfig,
    /// `pairs`, where an iteration writes the smoothed thermo.
    scratch: wgpu::Buffer,
    /// The particles' thermo array the scratch is copied back into.
    thermo: wgpu::Buffer,
    thermo_bytes: u64,
}

impl SmoothingStage {
    pub fn new(ctx: &Context, cfg: &ShotConfig, b: &ParticleBuffers) -> Result<Self> {
        let program = Program::new(ctx)?;
        let params = ParamSlots::single(ctx, "smoothing params", &SmoothParams::new(cfg, 1.0));
        let limiter = b.quarter(&b.pred, 0);
        let factor = b.quarter(&b.pred, 1);
        let own = [
            ("S", params.slot(0)),
            ("thermo_in", b.thermo.as_entire_binding()),
            ("thermo_out", b.pairs.as_entire_binding()),
            ("vapor_limit_of", limiter.binding()),
            ("smooth_factor_of", factor.binding()),
        ];
        let bind = program.bind(ctx, &[&own, b])?;
        Ok(Self {
            program,
            params,
            bind,
            cfg: cfg.clone(),
            thermo_bytes: b.slots as u64 * 16,
            scratch: b.pairs.clone(),
            thermo: b.thermo.clone(),
        })
    }

    /// Iterations per substep the config asks for (0 when neither temperature smoothing nor
    /// vapor mixing is on).
    pub fn iterations(&self) -> u32 {
        let s = &self.cfg.physics.smoothing;
        if s.enabled || s.vapor_diffusivity > 0.0 {
            s.iterations
        } else {
            0
        }
    }

    /// Records the configured iterations for a substep of `dt` seconds.
    pub fn smooth(&self, rec: &mut Recorder, live: &LiveBuffer, dt: f64) -> Result<()> {
        let params = SmoothParams::new(&self.cfg, dt);
        self.smooth_params(rec, live, &params, self.iterations())
    }

    /// As [`Self::smooth`] with explicit parameters and iteration count (tests share them with
    /// the mirror).
    pub(crate) fn smooth_params(
        &self,
        rec: &mut Recorder,
        live: &LiveBuffer,
        params: &SmoothParams,
        iterations: u32,
    ) -> Result<()> {
        if iterations == 0 {
            return Ok(());
        }
        let mixing = params.vapor_rate > 0.0;
        self.params.write(rec.ctx(), 0, params);
        for _ in 0..iterations {
            {
                let mut pass = rec.pass();
                let group = [(&self.bind, 0)];
                let live = Dispatch::Live(live);
                if mixing {
                    let limit = SmoothingEntry::VaporLimit;
                    self.program.dispatch(&mut pass, limit, &group, live);
                }
                if params.conservative != 0 {
                    let factor = SmoothingEntry::Factor;
                    self.program.dispatch(&mut pass, factor, &group, live);
                }
                let smooth = SmoothingEntry::SmoothTemperature;
                self.program.dispatch(&mut pass, smooth, &group, live);
            }
            // the whole array: the live count is on the GPU; slots past it are dead
            rec.encoder().copy_buffer_to_buffer(
                &self.scratch,
                0,
                &self.thermo,
                0,
                self.thermo_bytes,
            );
        }
        Ok(())
    }
}

impl Stage for SmoothingStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        Self::new(setup.ctx, setup.shot.config(), setup.buffers)
    }

    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        match phase {
            Phase::Smoothing => self.smooth(rec, sub.live, sub.dt),
            other => Err(crate::sim::stage::not_recorded("smoothing", other)),
        }
    }

    fn device_bytes(&self) -> u64 {
        self.params.size()
    }
}

/// The fraction a relaxation applies over `share` reference intervals when it applies `c` over
/// one: `1 - (1 - c)^share` (c = 1 stays 1).
pub fn rate_share(c: f64, share: f64) -> f64 {
    if c >= 1.0 {
        return 1.0;
    }
    -((share * (-c).ln_1p()).exp_m1())
}

#[cfg(test)]
mod tests {
    #[test]
    fn params_layout_matches_wgsl() {
        assert_eq!(std::mem::size_of::<super::SmoothParams>(), 48);
    }
}
