//! The GPU half that every force of its own shares: one pass over the live particles with a
//! uniform of its own, bound beside the shared particle buffers (`Setup::buffers`). A force
//! module keeps what is its own (the uniform's contents, when it runs, its frame figures).
use crate::error::Result;
use crate::gpu::buffers::ParamSlots;
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{Dispatch, Entry, Program};
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Substep};

/// One compute pass of entry `E` reading the uniform `P`.
pub struct ParticlePass<E: Entry, P: bytemuck::Pod> {
    program: Program<E>,
    params: ParamSlots<P>,
    bind: wgpu::BindGroup,
    entry: E,
}

impl<E: Entry, P: bytemuck::Pod> ParticlePass<E, P> {
    /// Builds the pass; its WGSL names the uniform `name` (labelled `label` on the device) and
    /// starts with `first`.
    pub fn new(
        setup: &Setup,
        entry: E,
        name: &'static str,
        label: &str,
        first: &P,
    ) -> Result<Self> {
        let program = Program::new(setup.ctx)?;
        let params = ParamSlots::single(setup.ctx, label, first);
        let own = [(name, params.slot(0))];
        let bind = program.bind(setup.ctx, &[&own, setup.buffers])?;
        Ok(Self {
            program,
            params,
            bind,
            entry,
        })
    }

    /// Records the pass over the live particles with `params`.
    pub fn record(&self, rec: &mut Recorder, live: &LiveBuffer, params: &P) -> Result<()> {
        self.params.write(rec.ctx(), 0, params);
        self.program.dispatch(
            &mut rec.pass(),
            self.entry,
            &[(&self.bind, 0)],
            Dispatch::Live(live),
        );
        Ok(())
    }

    /// Device memory of its own (the uniform).
    pub fn device_bytes(&self) -> u64 {
        self.params.size()
    }
}

/// `Stage::record` of a force that acts once a frame, from a table of the frame's start: the
/// pass with `params` in the forces phase of the frame's first substep, nothing in the others.
pub fn record_once_a_frame<E: Entry, P: bytemuck::Pod>(
    force: &'static str,
    pass: &ParticlePass<E, P>,
    params: &P,
    phase: Phase,
    rec: &mut Recorder,
    sub: &Substep,
) -> Result<()> {
    match phase {
        Phase::Forces if sub.first => pass.record(rec, sub.live, params),
        Phase::Forces => Ok(()),
        other => Err(crate::sim::stage::not_recorded(force, other)),
    }
}
