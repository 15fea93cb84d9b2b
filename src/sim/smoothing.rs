//! Temperature smoothing as a constraint (paper section 4.1, eqs. 12-17); see
//! docs/PHYSICS.md for what it does and how the isolation diagnostic measures it.
//!
//! One Jacobi iteration (shaders/smoothing.wgsl, entry `smooth_temperature`; f64 mirror
//! `sim::reference::smoothing::smooth_temperature`) reads the temperatures and writes the
//! smoothed ones into a scratch buffer owned by the stage, which is then copied back into
//! `thermo`; `physics.smoothing.iterations` such iterations run per substep, none when
//! `physics.smoothing.enabled` is false and `physics.smoothing.vapor_diffusivity` is 0 (the same
//! pass mixes vapor between neighbours, docs/PHYSICS.md "Vapor mixing"). Neighbours come from
//! the cell table (27 cells, minimum-image displacement); with `physics.smoothing.walls: fixed` the boundary particles take
//! part with their fixed temperature, by default (insulated) they are left out.
//!
//! Usage: `let mut stage = SmoothingStage::new(&ctx, &cfg)?;` once, then per substep
//! `stage.encode(&mut encoder, &SmoothingBuffers { .. }, count)`. The scratch buffer grows to
//! the largest `count` seen (hence `&mut self`).
use crate::config::ShotConfig;
use crate::error::Result;
use crate::gpu::{self, Context};
use crate::sim::thermo::{dispatch_size, entry};

const SHADER: &str = "smoothing.wgsl";
const ENTRY: &str = "smooth_temperature";
const LIMIT_ENTRY: &str = "vapor_limit";

/// Uniform of shaders/smoothing.wgsl (same layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SmoothParams {
    pub count: u32,
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
    pub _pad2: u32,
}

impl SmoothParams {
    /// Parameters of one iteration in a substep of `dt` seconds: `physics.smoothing.kappa` is
    /// the fraction applied per `solver.reference_step` seconds, so an iteration applies
    /// `1 - (1 - kappa)^(dt / (reference_step iterations))` and a frame smooths as much at 2
    /// substeps as at 8 (docs/PHYSICS.md "Substeps").
    pub fn new(cfg: &ShotConfig, count: u32, dt: f64) -> Self {
        let s = &cfg.physics.smoothing;
        let iterations = s.iterations.max(1) as f64;
        let share = dt / (cfg.solver.reference_step * iterations);
        Self {
            count,
            h0: (cfg.domain.spacing * cfg.domain.kernel_ratio) as f32,
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
            _pad2: 0,
        }
    }
}

/// The arrays one smoothing iteration reads (particles in cell order, see docs/ARCHITECTURE.md).
pub struct SmoothingBuffers<'a> {
    /// `GridParams` uniform (src/sim/grid_params.rs).
    pub grid: &'a wgpu::Buffer,
    /// `array<vec4<f32>>` positions.
    pub pos: &'a wgpu::Buffer,
    /// `array<vec2<u32>>` (id, level).
    pub info: &'a wgpu::Buffer,
    /// `array<vec4<f32>>` (T, v, w, E); T is smoothed in place (through the scratch buffer).
    pub thermo: &'a wgpu::Buffer,
    /// `array<u32>`, `GridParams::table_len` entries.
    pub cell_start: &'a wgpu::Buffer,
    /// `array<vec4<f32>>` boundary particles (xyz, w = temperature), in cell order.
    pub boundary: &'a wgpu::Buffer,
    /// `array<u32>`, `GridParams::table_len` entries.
    pub boundary_cell_start: &'a wgpu::Buffer,
}

pub struct SmoothingStage {
    device: wgpu::Device,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    limit_pipeline: wgpu::ComputePipeline,
    limit_layout: wgpu::BindGroupLayout,
    cfg: ShotConfig,
    scratch: Option<(wgpu::Buffer, u32)>,
    /// The vapor-mixing limiter per particle (f32), `count` long while mixing is on; one
    /// element otherwise (bound, never read: no cost when mixing is off).
    limit: Option<(wgpu::Buffer, u32)>,
}

impl SmoothingStage {
    pub fn new(ctx: &Context, cfg: &ShotConfig) -> Result<Self> {
        let pipeline = gpu::shaders::compute_pipeline(&ctx.device, SHADER, ENTRY)?;
        let layout = pipeline.get_bind_group_layout(0);
        let limit_pipeline = gpu::shaders::compute_pipeline(&ctx.device, SHADER, LIMIT_ENTRY)?;
        let limit_layout = limit_pipeline.get_bind_group_layout(0);
        Ok(Self {
            device: ctx.device.clone(),
            pipeline,
            layout,
            limit_pipeline,
            limit_layout,
            cfg: cfg.clone(),
            scratch: None,
            limit: None,
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

    /// Records the configured number of iterations for the first `count` particles, for a
    /// substep of `dt` seconds.
    pub fn encode(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        bufs: &SmoothingBuffers,
        count: u32,
        dt: f64,
    ) {
        let params = SmoothParams::new(&self.cfg, count, dt);
        let iterations = self.iterations();
        self.encode_params(encoder, bufs, &params, iterations);
    }

    /// As [`Self::encode`] with explicit parameters and iteration count (used by tests).
    pub fn encode_params(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        bufs: &SmoothingBuffers,
        params: &SmoothParams,
        iterations: u32,
    ) {
        let count = params.count;
        if count == 0 || iterations == 0 {
            return;
        }
        if self.scratch.as_ref().is_none_or(|(_, cap)| *cap < count) {
            let buf = gpu::buffers::storage_zeroed::<[f32; 4]>(
                &self.device,
                "smoothing scratch",
                count as usize,
            );
            self.scratch = Some((buf, count));
        }
        let mixing = params.vapor_rate > 0.0;
        let limit_len = if mixing { count } else { 1 };
        if self.limit.as_ref().is_none_or(|(_, cap)| *cap < limit_len) {
            let buf = gpu::buffers::storage_zeroed::<f32>(
                &self.device,
                "vapor mixing limiter",
                limit_len as usize,
            );
            self.limit = Some((buf, limit_len));
        }
        let (Some((scratch, _)), Some((limit, _))) = (&self.scratch, &self.limit) else {
            return;
        };
        let uniform = gpu::buffers::uniform_init(&self.device, "smoothing params", params);
        let entries = [
            entry(0, bufs.grid),
            entry(1, &uniform),
            entry(2, bufs.pos),
            entry(3, bufs.info),
            entry(4, bufs.thermo),
            entry(5, scratch),
            entry(6, bufs.cell_start),
            entry(7, bufs.boundary),
            entry(8, bufs.boundary_cell_start),
            entry(9, limit),
        ];
        let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("smoothing"),
            layout: &self.layout,
            entries: &entries,
        });
        // vapor_limit writes no temperatures and reads no boundary particles: its auto layout
        // leaves bindings 5, 7 and 8 out.
        let limit_bind = mixing.then(|| {
            let used: Vec<_> = entries
                .iter()
                .filter(|e| ![5, 7, 8].contains(&e.binding))
                .cloned()
                .collect();
            self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("vapor limit"),
                layout: &self.limit_layout,
                entries: &used,
            })
        });
        let bytes = count as u64 * 16;
        let (x, y) = dispatch_size(count);
        for _ in 0..iterations {
            if let Some(limit_bind) = &limit_bind {
                dispatch(
                    encoder,
                    LIMIT_ENTRY,
                    &self.limit_pipeline,
                    limit_bind,
                    (x, y),
                );
            }
            dispatch(encoder, ENTRY, &self.pipeline, &bind, (x, y));
            encoder.copy_buffer_to_buffer(scratch, 0, bufs.thermo, 0, bytes);
        }
    }
}

fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    label: &str,
    pipeline: &wgpu::ComputePipeline,
    bind: &wgpu::BindGroup,
    (x, y): (u32, u32),
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind, &[]);
    pass.dispatch_workgroups(x, y, 1);
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
        assert_eq!(std::mem::size_of::<super::SmoothParams>(), 32);
    }
}
