//! The neighbour grid build of a substep (shaders/grid.wgsl, gpu::scan, shared/permute.wgsl;
//! f64 mirror `sim::reference::grid`): (cell, x slice) keys of the predicted positions, a
//! counting sort by key (counts, their scan into the cell table, a scatter, each entry's
//! particles in index order: the order of a stable sort), and every particle array (x, p*, thermo,
//! info) gathered into cell order. The permutation gathers into the velocity array, dead
//! between prediction and velocity update, and copies back.
use crate::error::Result;
use crate::gpu::buffers::{range, storage_zeroed, Span};
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{entry_points, Dispatch, Entry, Program};
use crate::gpu::scan::{PrefixScan, ScanOf};
use crate::gpu::Context;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::grid_params::GridParams;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};

entry_points! {
    /// The entry points of shaders/grid.wgsl, in the order of a build.
    pub enum GridEntry in "grid.wgsl" {
        CellClear = "cell_clear", CellKeys = "cell_keys",
        CellScatter = "cell_scatter", CellOrder = "cell_order",
    }
    /// Gathers a `vec4` array into cell order (into the velocity array) and copies it back.
    pub enum Permute4Entry in "permute4.wgsl" { Gather = "permute4", CopyBack = "copy4" }
    /// The same for a `vec2<u32>` array.
    pub enum Permute2Entry in "permute2.wgsl" { Gather = "permute2", CopyBack = "copy2" }
}

pub struct GridStage {
    keys: Program<GridEntry>,
    perm4: Program<Permute4Entry>,
    perm2: Program<Permute2Entry>,
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
        let keys = Program::new(ctx)?;
        let perm4 = Program::new(ctx)?;
        let perm2 = Program::new(ctx)?;
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
        let perm4_bind = |src, dst| permute_bind(ctx, &perm4, b, order(), src, dst);
        let perm2_bind = |src, dst| permute_bind(ctx, &perm2, b, order(), src, dst);
        let perm4_binds = [&b.pos, &b.pred, &b.thermo]
            .iter()
            .map(|a| Ok((perm4_bind(a, &b.vel)?, perm4_bind(&b.vel, a)?)))
            .collect::<Result<Vec<_>>>()?;
        let perm2_binds = (perm2_bind(&b.info, &b.vel)?, perm2_bind(&b.vel, &b.info)?);
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
        let mut pass = rec.pass();
        let p = &mut pass;
        let live_n = Dispatch::Live(live);
        let bind = [(&self.keys_bind, 0)];
        let entries = Dispatch::Threads(self.table_len);
        self.keys.dispatch(p, GridEntry::CellClear, &bind, entries);
        self.keys.dispatch(p, GridEntry::CellKeys, &bind, live_n);
        self.scan.encode(p, 0);
        self.keys.dispatch(p, GridEntry::CellScatter, &bind, live_n);
        self.keys.dispatch(p, GridEntry::CellOrder, &bind, live_n);
        for (gather, back) in &self.perm4_binds {
            self.perm4
                .dispatch(p, Permute4Entry::Gather, &[(gather, 0)], live_n);
            self.perm4
                .dispatch(p, Permute4Entry::CopyBack, &[(back, 0)], live_n);
        }
        let (gather, back) = &self.perm2_binds;
        self.perm2
            .dispatch(p, Permute2Entry::Gather, &[(gather, 0)], live_n);
        self.perm2
            .dispatch(p, Permute2Entry::CopyBack, &[(back, 0)], live_n);
        Ok(())
    }
}

/// A bind group of a permutation: `src` gathered by `order` into `dst`.
fn permute_bind<E: Entry>(
    ctx: &Context,
    program: &Program<E>,
    b: &ParticleBuffers,
    order: wgpu::BindingResource,
    src: &wgpu::Buffer,
    dst: &wgpu::Buffer,
) -> Result<wgpu::BindGroup> {
    let own = [
        ("order", order),
        ("src", src.as_entire_binding()),
        ("dst", dst.as_entire_binding()),
    ];
    program.bind(ctx, &[&own, b])
}

impl Stage for GridStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        Self::new(setup.ctx, setup.grid, setup.buffers)
    }

    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        match phase {
            Phase::Grid => self.build(rec, sub.live),
            other => Err(crate::sim::stage::not_recorded("grid", other)),
        }
    }

    fn device_bytes(&self) -> u64 {
        self.scan.device_bytes() + self.counts_own.as_ref().map_or(0, |c| c.size())
    }
}
