//! Test hooks (cargo feature `test-hooks`, which the crate's own tests turn on; not part of
//! the public API): run one PBF entry point or the grid build alone, and read or overwrite device
//! arrays, so that tests can compare a stage with its f64 mirror on fresh random inputs.
use crate::error::Result;
use crate::gpu::buffers::read_back;
use crate::gpu::live::LiveBuffer;
use crate::gpu::Context;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::pbf::PbfEntry;
use crate::sim::phase::Recorder;
use crate::sim::smoothing::{SmoothParams, SmoothingStage};
use crate::sim::thermo::{ThermoParams, ThermoStage};
use crate::sim::Simulation;
use std::sync::Arc;

/// Parts of a substep a test may run one at a time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    Predict,
    Grid,
    /// compute_lambda of a substep's first iteration (builds the neighbour mask)
    Lambda,
    /// compute_lambda of the later iterations (the mask's neighbours)
    LambdaMasked,
    Delta,
    UpdateVelocity,
    Vorticity,
    ViscosityConfine,
    /// the rest of the substep after `ViscosityConfine`: x = p*, the density at it
    Finish,
}

/// Device arrays a test may read or overwrite.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Buf {
    Pos,
    Vel,
    Pred,
    /// (p*, lambda) after `Step::Lambda`, v after `Step::UpdateVelocity`
    Scratch,
    Density,
    CellStart,
    Info,
}

impl Simulation {
    /// Runs one part of the substep alone (and waits for it).
    pub fn run_step(&mut self, step: Step) -> Result<()> {
        let ctx = self.ctx.clone();
        let mut rec = Recorder::new(&ctx, None, None);
        let (pbf, live) = (&self.s.pbf, &self.b.live);
        let entry = match step {
            Step::Predict => PbfEntry::Predict,
            Step::Lambda => PbfEntry::ComputeLambda,
            Step::LambdaMasked => PbfEntry::ComputeLambdaMasked,
            Step::Delta => PbfEntry::ComputeDelta,
            Step::UpdateVelocity => PbfEntry::UpdateVelocity,
            Step::Vorticity => PbfEntry::Vorticity,
            Step::ViscosityConfine => PbfEntry::ViscosityConfine,
            Step::Finish => PbfEntry::FinishPositions,
            Step::Grid => {
                self.s.grid.build(&mut rec, live)?;
                rec.submit();
                return ctx.wait();
            }
        };
        pbf.run(&mut rec.pass(), entry, live);
        rec.submit();
        ctx.wait()
    }

    fn buffer(&self, which: Buf) -> &wgpu::Buffer {
        let b = &self.b;
        match which {
            Buf::Pos => &b.pos,
            Buf::Vel => &b.vel,
            Buf::Pred => &b.pred,
            Buf::Scratch => &b.pairs,
            Buf::Density => &b.density,
            Buf::CellStart => &b.cell_start,
            Buf::Info => &b.info,
        }
    }

    pub fn read_vec4(&self, which: Buf) -> Result<Vec<[f32; 4]>> {
        read_back(&self.ctx, self.buffer(which), self.count())
    }
    pub fn read_f32(&self, which: Buf) -> Result<Vec<f32>> {
        read_back(&self.ctx, self.buffer(which), self.count())
    }
    pub fn read_u32(&self, which: Buf, len: usize) -> Result<Vec<u32>> {
        read_back(&self.ctx, self.buffer(which), len)
    }
    /// Overwrites the first entries of an array (tests seed fresh random inputs this way).
    pub fn write<T: bytemuck::Pod>(&self, which: Buf, data: &[T]) {
        self.ctx
            .queue
            .write_buffer(self.buffer(which), 0, bytemuck::cast_slice(data));
    }

    /// The live state on the GPU (count, next id, single-level flag, dispatch arguments).
    pub fn live(&self) -> Result<crate::gpu::live::Live> {
        Ok(read_back::<crate::gpu::live::Live>(&self.ctx, self.b.live.buffer(), 1)?[0])
    }

    /// The device arrays (a test runs another stage over them).
    pub fn buffers(&self) -> &ParticleBuffers {
        &self.b
    }

    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }
}

impl SmoothingStage {
    /// `smooth` with explicit parameters and iteration count (the tests share them with the
    /// mirror).
    pub fn smooth_with(
        &self,
        rec: &mut Recorder,
        live: &LiveBuffer,
        params: &SmoothParams,
        iterations: u32,
    ) -> Result<()> {
        self.smooth_params(rec, live, params, iterations)
    }
}

impl ThermoStage {
    /// `step` with explicit parameters (the tests share them with the mirror).
    pub fn step_with(
        &self,
        rec: &mut Recorder,
        live: &LiveBuffer,
        params: &ThermoParams,
    ) -> Result<()> {
        self.step_params(rec, live, params)
    }
}
