//! The neighbour grid build of a substep (shaders/grid.wgsl, gpu::scan, shared/permute.wgsl;
//! f64 mirror `sim::reference::grid`): (cell, x slice) keys of the predicted positions, a
//! counting sort by key (counts, their scan into the cell table, a scatter, each entry's
//! particles in index order: the order of a stable sort), and every particle array (x, p*, thermo,
//! info) gathered into cell order. The permutation gathers into the velocity array, dead
//! between prediction and velocity update, and copies back.
use crate::error::Result;
use crate::gpu::buffers::{range, storage_zeroed, Span};
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{Dispatch, Program};
use crate::gpu::scan::{PrefixScan, ScanOf};
use crate::gpu::Context;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::grid_params::GridParams;
use crate::sim::phase::{Phase, Recorder};

pub struct GridStage {
    keys: Program,
    perm4: Program,
    perm2: Program,
    /// counts -> cell_start
    scan: PrefixScan,
    keys_bind: wgpu::BindGroup,
    /// (gather into vel, copy back) for pos, pred, thermo; the same for info.
    perm4_binds: Vec<(wgpu::BindGroup, wgpu::BindGroup)>,
    perm2_binds: (wgpu::BindGroup, wgpu::BindGroup),
    /// The counts' own buffer, where the table does not fit an array of the pairs buffer.
    counts_own: Option<wgpu::Buffer>,
    table_len: u32,
}

impl GridStage {
    pub fn new(ctx: &Context, grid: &GridParams, b: &ParticleBuffers) -> Result<Self> {
        let keys = Program::new(
            ctx,
            "grid.wgsl",
            &["cell_clear", "cell_keys", "cell_scatter", "cell_order"],
        )?;
        let perm4 = Program::new(ctx, "permute4.wgsl", &["permute4", "copy4"])?;
        let perm2 = Program::new(ctx, "permute2.wgsl", &["permute2", "copy2"])?;
        let table_len = grid.table_len() as u32;
        // the pairs buffer (dead outside the solve): keys, order, the counts where the table
        // fits one of its arrays (every filled box: ~0.25 entries per particle), the scatter
        let arr = b.slots as u64 * 4;
        let counts_bytes = table_len as u64 * 4;
        // the scan reads its input in quads (arr is a multiple of 256 bytes)
        let quad_bytes = counts_bytes.next_multiple_of(16);
        let counts_own = (quad_bytes > arr)
            .then(|| storage_zeroed::<u32>(&ctx.device, "cell counts", quad_bytes as usize / 4));
        let counts = match &counts_own {
            Some(buf) => Span::new(buf, 0, quad_bytes),
            None => Span::new(&b.pairs, 2 * arr, quad_bytes),
        };
        let scan = PrefixScan::new(
            ctx,
            &counts,
            Some(Span::new(&b.cell_start, 0, counts_bytes)),
            table_len,
            &b.live,
            &[ScanOf::Values],
        )?;
        let order = || range(&b.pairs, arr, arr);
        let own = [
            ("pos_in", b.pred.as_entire_binding()),
            ("keys", range(&b.pairs, 0, arr)),
            ("order", order()),
            ("counts", counts.binding()),
            ("scattered", range(&b.pairs, 3 * arr, arr)),
        ];
        let keys_bind = keys.bind(ctx, &[&own, b])?;
        let perm = |stage: &Program, src: &wgpu::Buffer, dst: &wgpu::Buffer| {
            let own = [
                ("order", order()),
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
            keys_bind,
            perm4_binds,
            perm2_binds,
            keys,
            perm4,
            perm2,
            scan,
            counts_own,
            table_len,
        })
    }

    /// Records the grid build of the live particles.
    pub fn build(&self, rec: &mut Recorder, live: &LiveBuffer) -> Result<()> {
        {
            let mut pass = rec.pass(Phase::Grid);
            let p = &mut pass;
            let live_n = Dispatch::Live(live);
            let bind = [(&self.keys_bind, 0)];
            let entries = Dispatch::Threads(self.table_len);
            self.keys.dispatch(p, "cell_clear", &bind, entries);
            self.keys.dispatch(p, "cell_keys", &bind, live_n);
            self.scan.encode(p, 0);
            self.keys.dispatch(p, "cell_scatter", &bind, live_n);
            self.keys.dispatch(p, "cell_order", &bind, live_n);
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
        self.scan.device_bytes() + self.counts_own.as_ref().map_or(0, |c| c.size())
    }
}
