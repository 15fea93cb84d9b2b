//! The neighbour grid build of a substep (shaders/grid.wgsl, gpu::sort, shared/permute.wgsl;
//! f64 mirror `sim::reference::grid`): (cell, x slice) keys of the predicted positions, a
//! stable radix sort, the cell table, and every particle array (x, p*, thermo, info) gathered
//! into cell order. The permutation gathers into the velocity array, dead between prediction and
//! velocity update, and copies back.
use crate::error::Result;
use crate::gpu::buffers::range;
use crate::gpu::live::LiveBuffer;
use crate::gpu::sort::{key_bits, RadixSort};
use crate::gpu::stage::{Dispatch, Stage};
use crate::gpu::Context;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::grid_params::GridParams;
use crate::sim::phase::{Phase, Recorder};

pub struct GridStage {
    keys: Stage,
    perm4: Stage,
    perm2: Stage,
    sort: RadixSort,
    keys_bind: wgpu::BindGroup,
    table_bind: wgpu::BindGroup,
    /// (gather into vel, copy back) for pos, pred, thermo; the same for info.
    perm4_binds: Vec<(wgpu::BindGroup, wgpu::BindGroup)>,
    perm2_binds: (wgpu::BindGroup, wgpu::BindGroup),
}

impl GridStage {
    pub fn new(ctx: &Context, grid: &GridParams, b: &ParticleBuffers) -> Result<Self> {
        let keys = Stage::new(ctx, "grid.wgsl", &["cell_keys", "cell_table"])?;
        let perm4 = Stage::new(ctx, "permute4.wgsl", &["permute4", "copy4"])?;
        let perm2 = Stage::new(ctx, "permute2.wgsl", &["permute2", "copy2"])?;
        let bits = key_bits(grid.table_len() as u32 - 2);
        let sort = RadixSort::new(ctx, &b.pairs, b.capacity, bits, &b.live)?;
        let arr = b.capacity as u64 * 4;
        let (ko, vo) = sort.result_offsets();
        // the keys of the predicted positions, sorted in the pairs buffer's arrays
        let grid_bind = |keys_at: u64, vals_at: u64| {
            let own = [
                ("pos_in", b.pred.as_entire_binding()),
                ("keys", range(&b.pairs, keys_at, arr)),
                ("vals", range(&b.pairs, vals_at, arr)),
            ];
            keys.bind(ctx, &[&own, b])
        };
        let perm = |stage: &Stage, src: &wgpu::Buffer, dst: &wgpu::Buffer| {
            let own = [
                ("order", range(&b.pairs, vo, arr)),
                ("src", src.as_entire_binding()),
                ("dst", dst.as_entire_binding()),
            ];
            stage.bind(ctx, &[&own, b])
        };
        let perm4_binds = [&b.pos, &b.pred, &b.thermo]
            .iter()
            .map(|a| Ok((perm(&perm4, a, &b.vel)?, perm(&perm4, &b.vel, a)?)))
            .collect::<Result<Vec<_>>>()?;
        let perm2_binds = (
            perm(&perm2, &b.info, &b.vel)?,
            perm(&perm2, &b.vel, &b.info)?,
        );
        Ok(Self {
            keys_bind: grid_bind(0, arr)?,
            table_bind: grid_bind(ko, vo)?,
            perm4_binds,
            perm2_binds,
            keys,
            perm4,
            perm2,
            sort,
        })
    }

    /// Records the grid build of the live particles.
    pub fn build(&self, rec: &mut Recorder, live: &LiveBuffer) -> Result<()> {
        {
            let mut pass = rec.pass(Phase::Grid);
            let p = &mut pass;
            let live_n = Dispatch::Live(live);
            self.keys
                .dispatch(p, "cell_keys", &[(&self.keys_bind, 0)], live_n);
            self.sort.encode(p, live);
            self.keys
                .dispatch(p, "cell_table", &[(&self.table_bind, 0)], live_n);
            for (gather, back) in &self.perm4_binds {
                self.perm4.dispatch(p, "permute4", &[(gather, 0)], live_n);
                self.perm4.dispatch(p, "copy4", &[(back, 0)], live_n);
            }
            let (gather, back) = &self.perm2_binds;
            self.perm2.dispatch(p, "permute2", &[(gather, 0)], live_n);
            self.perm2.dispatch(p, "copy2", &[(back, 0)], live_n);
        }
        rec.end_phase(Phase::Grid)
    }

    pub fn device_bytes(&self) -> u64 {
        self.sort.device_bytes()
    }
}
