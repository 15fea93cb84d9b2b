//! Adaptive particles (paper section 5.2): shape energy, split and merge on the GPU.
//!
//! A stage over the particle buffers of docs/ARCHITECTURE.md (cell-ordered, with the cell table
//! of the last grid build), recorded at the end of every substep without a host round trip
//! (three phases, marks, merges and splits, each a call of its `Stage::record`):
//! 1. `adaptive_mark`: E = kp (1 - exp(-kc w)) into `thermo.w`; merge marks (E < beta, l > 0);
//!    split marks (E > alpha, l < max_level) where both children fit (min_distance);
//! 2. `merge_cells` lists, per grid colour, the cells holding a merge mark with a merge-marked
//!    partner on its level in reach (no other cell can merge) and `merge_dispatch`
//!    writes one indirect dispatch per colour; `adaptive_merge`, a workgroup per listed cell:
//!    pairs of marked same-level neighbours become one particle of level l-1 in the lower slot,
//!    the other slot dies;
//! 3. scan of dead flags, `compact_holes` + `compact_move`: in-place deterministic compaction;
//! 4. scan of split marks, `totals_split` (the new live state), `adaptive_split`: children
//!    appended after the live range, up to the capacity (excess splits skipped and counted);
//!    the new live state is copied over `live` (gpu::live), so the next kernels and dispatches
//!    see the new count;
//!    it also counts the particles per level into the counters, read back with the frame.
//!
//! Marks and the split room check read one snapshot (before any merge), so neither depends on
//! the other's outcome. The f64 mirrors are in `sim::reference` (one file per shader).
use crate::config::AdaptiveConfig;
use crate::error::{Error, Result};
use crate::gpu::buffers::{self, ParamSlots};
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{entry_points, Dispatch, Entry, Program, Resources};
use crate::gpu::scan::{PrefixScan, ScanOf};
use crate::gpu::Context;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::grid_params::GridParams;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};

entry_points! {
    /// Shape energy, merge and split marks.
    pub enum MarkEntry in "adaptive_mark.wgsl" { Mark = "adaptive_mark" }
    /// The cells to merge per colour, and one indirect dispatch per colour.
    pub enum PlanEntry in "adaptive_plan.wgsl" {
        Cells = "merge_cells", Dispatches = "merge_dispatch",
    }
    /// A workgroup per listed cell of a colour.
    pub enum MergeEntry in "adaptive_merge.wgsl" { Merge = "adaptive_merge" }
    /// The in-place compaction of the dead slots.
    pub enum CompactEntry in "adaptive_compact.wgsl" {
        Holes = "compact_holes", Move = "compact_move",
    }
    /// The children, appended after the live range.
    pub enum SplitEntry in "adaptive_split.wgsl" { Split = "adaptive_split" }
    /// The run's totals after the merges and after the splits.
    pub enum StatsEntry in "adaptive_stats.wgsl" {
        Merges = "totals_merge", Splits = "totals_split",
    }
}

/// Largest `min_distance` the room check's 27 cells allow (a limit of the config's range).
pub use crate::config::MAX_MIN_DISTANCE;

// Flags of one run (shaders/shared/adaptive.wgsl).
pub const FLAG_MERGE: u32 = 1;
pub const FLAG_SPLIT: u32 = 2;
pub const FLAG_MERGED: u32 = 4;
pub const FLAG_DEAD: u32 = 8;

// Counters layout (shaders/shared/adaptive.wgsl).
const C_MERGES: usize = 0;
const C_SPLITS: usize = 3;
const C_SKIPPED: usize = 4;
const C_FINAL: usize = 5;
const C_NEXT_ID: usize = 6;
const C_LEVELS: usize = 8;

/// Uniform of every adaptive shader (mirror of `AdaptiveParams` in shaders/shared/adaptive.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AdaptiveParams {
    pub count: u32,
    pub capacity: u32,
    pub max_level: u32,
    pub next_id: u32,
    pub h0: f32,
    pub kp: f32,
    pub kc: f32,
    pub split_threshold: f32,
    pub merge_threshold: f32,
    pub min_distance: f32,
    pub split_offset: f32,
    pub pad0: u32,
}

impl AdaptiveParams {
    /// The parameters of a prepared shot's `adaptive` section (its ranges and order checked
    /// there, `shot::Shot`); count and next_id are set per run.
    pub fn new(cfg: &AdaptiveConfig, h0: f64, capacity: u32) -> Self {
        Self {
            count: 0,
            capacity,
            max_level: cfg.max_level,
            next_id: 0,
            h0: h0 as f32,
            kp: cfg.kp as f32,
            kc: cfg.kc as f32,
            split_threshold: cfg.split_threshold as f32,
            merge_threshold: cfg.merge_threshold as f32,
            min_distance: cfg.min_distance as f32,
            split_offset: cfg.split_offset as f32,
            pad0: 0,
        }
    }
}

/// Cells of one merge pass: `start + 3 t` per axis for `t < count` (mirror of `ColourPass`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ColourPass {
    pub start: [u32; 4],
    pub count: [u32; 4],
}

impl ColourPass {
    pub fn cells(&self) -> u32 {
        self.count[0] * self.count[1] * self.count[2]
    }
    /// Integer coordinates of the t-th cell of the pass (same order as the shader).
    pub fn cell(&self, t: u32) -> [i32; 3] {
        let [cx, cy, _, _] = self.count;
        let tc = [t % cx, (t / cx) % cy, t / (cx * cy)];
        [0, 1, 2].map(|a| (self.start[a] + 3 * tc[a]) as i32)
    }
}

/// Classes of one axis: `(start, count)` with cells start, start + 3, ... Cells of a class are
/// at least 3 apart. On a periodic axis whose cell count is not a multiple of 3, the last one or two
/// cells get classes of their own, so no class has cells adjacent across the wrap.
fn axis_classes(dim: u32, periodic: bool) -> Vec<(u32, u32)> {
    let mut v = Vec::new();
    if periodic {
        let m = dim / 3;
        v.extend((0..3).map(|k| (k, m)));
        v.extend((0..dim % 3).map(|r| (3 * m + r, 1)));
    } else {
        v.extend((0..3.min(dim)).map(|k| (k, (dim - k).div_ceil(3))));
    }
    v.retain(|&(_, n)| n > 0);
    v
}

/// The merge passes of a grid (paper Fig. 4 with d = 1): 27 colours, plus the extra slabs of
/// periodic axes whose cell count is not a multiple of 3. Every cell is in exactly one pass.
pub fn colour_passes(grid: &GridParams) -> Vec<ColourPass> {
    let ax = axis_classes(grid.dims[0], grid.periodic_x());
    let ay = axis_classes(grid.dims[1], false);
    let az = axis_classes(grid.dims[2], grid.periodic_z());
    let mut out = Vec::new();
    for &(sz, nz) in &az {
        for &(sy, ny) in &ay {
            for &(sx, nx) in &ax {
                out.push(ColourPass {
                    start: [sx, sy, sz, 0],
                    count: [nx, ny, nz, 0],
                });
            }
        }
    }
    out
}

/// Outcome of one run of the stage (exact integers from the GPU counters).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AdaptiveReport {
    /// Live particles per level 0..=max_level after the run.
    pub per_level: Vec<u32>,
    pub splits: u32,
    pub merges: u32,
    /// Splits marked and with room for their children that the capacity refused.
    pub skipped_splits: u32,
    /// Live particles after the run.
    pub count: u32,
    /// Total mass in units of m0 2^(-max_level): a level-l particle holds 2^(max_level - l).
    pub mass_units: u64,
    /// The id the next new particle gets.
    pub next_id: u32,
}

/// Mass units of a level-l particle.
pub fn level_mass_units(level: u32, max_level: u32) -> u64 {
    1u64 << (max_level - level.min(max_level))
}

pub fn mass_units(per_level: &[u32], max_level: u32) -> u64 {
    per_level
        .iter()
        .enumerate()
        .map(|(l, &n)| n as u64 * level_mass_units(l as u32, max_level))
        .sum()
}

/// The colour of one merge dispatch (`MergeColour` in adaptive_merge.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MergeColour {
    pub index: u32,
    pub pad: [u32; 3],
}

/// How a cell's coordinates give its colour (`ColourMap` in adaptive_plan.wgsl): per axis,
/// cells below `split` take class x mod 3, the others classes 3.. of their own; `classes` per
/// axis. Colour = (class_z classes_y + class_y) classes_x + class_x, the order of
/// [`colour_passes`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ColourMap {
    pub split: [u32; 4],
    pub classes: [u32; 4],
}

impl ColourMap {
    pub fn of(grid: &GridParams) -> Self {
        let axis = |a: usize, periodic: bool| {
            let dim = grid.dims[a];
            let split = if periodic { 3 * (dim / 3) } else { u32::MAX };
            (split, axis_classes(dim, periodic).len() as u32)
        };
        let (sx, nx) = axis(0, grid.periodic_x());
        let (sy, ny) = axis(1, false);
        let (sz, nz) = axis(2, grid.periodic_z());
        Self {
            split: [sx, sy, sz, 0],
            classes: [nx, ny, nz, 0],
        }
    }

    /// The colour of cell `c` (mirror of adaptive_plan.wgsl).
    pub fn colour(&self, c: [u32; 3]) -> u32 {
        let class = |a: usize| {
            if c[a] < self.split[a] {
                c[a] % 3
            } else {
                3 + (c[a] - self.split[a])
            }
        };
        (class(2) * self.classes[1] + class(1)) * self.classes[0] + class(0)
    }
}

// Counters (shaders/shared/adaptive.wgsl).
const C_LIVE: usize = 32;
const C_FRAME_MERGES: usize = 44;
const N_COUNTERS: usize = 48;
/// Words of the merge load (adaptive_plan.wgsl): error, largest loop estimate, most listed cells.
const N_LOAD: usize = 4;

/// The frame's merge error from the load's words, if any (exit 3: the frame is not written).
pub fn load_error(load: &[u32], loop_budget: u32) -> Result<()> {
    if load.first().copied().unwrap_or(0) == 0 {
        return Ok(());
    }
    Err(Error::Runtime(format!(
        "adaptive: merging one crowded grid cell would take {} loop iterations, more than this \
         device runs in one invocation ({loop_budget}); lower the particle density or max_level",
        load[1]
    )))
}

/// Merges, splits and skipped splits summed over a frame (the counters' frame words).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameTotals {
    pub merges: u32,
    pub splits: u32,
    pub skipped_splits: u32,
}

/// The GPU split/merge stage, bound once to the particle buffers. Its per-particle scratch is
/// borrowed from arrays dead at the end of a substep: flags and holes from `pred`, the flags'
/// scan from `pairs`; it owns the counters, the merge cell lists (4 bytes per grid cell) and
/// small uniforms.
pub struct AdaptiveStage {
    params: AdaptiveParams,
    capacity: u32,
    mark: Program<MarkEntry>,
    merge: Program<MergeEntry>,
    plan: Program<PlanEntry>,
    compact: Program<CompactEntry>,
    split: Program<SplitEntry>,
    stats: Program<StatsEntry>,
    param_buf: ParamSlots<AdaptiveParams>,
    colour_map: ParamSlots<ColourMap>,
    colours: ParamSlots<MergeColour>,
    n_colours: u32,
    counters: wgpu::Buffer,
    load: wgpu::Buffer,
    /// The cells to merge, colour by colour; (list start, cells) per colour; listed per colour.
    cells: wgpu::Buffer,
    colour_list: wgpu::Buffer,
    colour_count: wgpu::Buffer,
    merge_args: wgpu::Buffer,
    loop_budget: u32,
    /// Exclusive scans of the dead flags (mode 0) and the split marks (mode 1).
    scan: PrefixScan,
    num_cells: u32,
    binds: Binds,
}

struct Binds {
    mark: wgpu::BindGroup,
    merge: wgpu::BindGroup,
    colour: wgpu::BindGroup,
    plan: wgpu::BindGroup,
    compact: wgpu::BindGroup,
    split: wgpu::BindGroup,
    stats: wgpu::BindGroup,
}

impl AdaptiveStage {
    /// Builds the stage over the particle buffers `b` on `grid` (its host copy: the merge
    /// colours follow its dims), kernel radius `h0` of level 0, of a prepared shot (`shot`).
    pub fn new(
        ctx: &Context,
        cfg: &AdaptiveConfig,
        grid: &GridParams,
        h0: f64,
        b: &ParticleBuffers,
    ) -> Result<Self> {
        let capacity = b.capacity;
        let params = AdaptiveParams::new(cfg, h0, capacity);
        // the grid of a prepared shot: cells of at least h0, 3 or more along a periodic axis
        let d = &ctx.device;
        let mark = Program::new(ctx)?;
        let merge = Program::new(ctx)?;
        let plan = Program::new(ctx)?;
        let compact = Program::new(ctx)?;
        let split = Program::new(ctx)?;
        let stats = Program::new(ctx)?;
        let param_buf = ParamSlots::single(ctx, "adaptive params", &params);
        let flags = b.quarter(&b.pred, 0);
        let hole_index = b.quarter(&b.pred, 1);
        let counters = buffers::storage_zeroed::<u32>(d, "adaptive counters", N_COUNTERS);
        let load = buffers::storage_zeroed::<u32>(d, "adaptive cell load", N_LOAD);
        let passes = colour_passes(grid);
        let n_colours = passes.len() as u32;
        let mut lists = Vec::with_capacity(passes.len());
        let mut start = 0u32;
        for c in &passes {
            lists.push([start, c.cells(), 0, 0]);
            start += c.cells();
        }
        let cells = buffers::storage_zeroed::<u32>(d, "adaptive merge cells", start as usize);
        let colour_list = buffers::storage_init(d, "adaptive colour lists", &lists);
        let colour_count =
            buffers::storage_zeroed::<u32>(d, "adaptive colour counts", passes.len());
        let merge_args = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("adaptive merge dispatches"),
            size: n_colours as u64 * 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT,
            mapped_at_creation: false,
        });
        let colour_map = ParamSlots::single(ctx, "adaptive colour map", &ColourMap::of(grid));
        let colours = ParamSlots::new(
            ctx,
            "adaptive merge colours",
            &(0..n_colours)
                .map(|index| MergeColour { index, pad: [0; 3] })
                .collect::<Vec<_>>(),
        );
        let scan = PrefixScan::new(
            ctx,
            &flags,
            Some(b.quarter(&b.pairs, 0)),
            capacity.max(1),
            &b.live,
            &[ScanOf::LiveFlags(FLAG_DEAD), ScanOf::LiveFlags(FLAG_SPLIT)],
        )?;
        // the stage's own buffers, by the names its shaders bind them by
        let own = [
            ("params", param_buf.slot(0)),
            ("flags", flags.binding()),
            ("scan", scan.output().binding()),
            ("hole_index", hole_index.binding()),
            ("counters", counters.as_entire_binding()),
            ("load", load.as_entire_binding()),
            ("cells", cells.as_entire_binding()),
            ("colour_list", colour_list.as_entire_binding()),
            ("colour_count", colour_count.as_entire_binding()),
            ("merge_args", merge_args.as_entire_binding()),
            ("colour_map", colour_map.slot(0)),
        ];
        let sources: [&dyn Resources; 2] = [&own, b];
        let binds = Binds {
            mark: mark.bind(ctx, &sources)?,
            merge: merge.bind(ctx, &sources)?,
            colour: merge.bind_group(ctx, 1, &[&[("colour", colours.slot(0))]])?,
            plan: plan.bind(ctx, &sources)?,
            compact: compact.bind(ctx, &sources)?,
            split: split.bind(ctx, &sources)?,
            stats: stats.bind(ctx, &sources)?,
        };
        Ok(Self {
            params,
            capacity,
            mark,
            merge,
            plan,
            compact,
            split,
            stats,
            param_buf,
            colour_map,
            colours,
            n_colours,
            counters,
            load,
            cells,
            colour_list,
            colour_count,
            merge_args,
            loop_budget: ctx.prelude.loop_budget,
            scan,
            num_cells: grid.num_cells,
            binds,
        })
    }

    pub fn params(&self) -> &AdaptiveParams {
        &self.params
    }

    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// The deepest level a split may reach.
    pub fn max_level(&self) -> u32 {
        self.params.max_level
    }

    /// The counters (`N_COUNTERS` u32: this run's totals, per-level counts, the frame's totals).
    pub fn counters(&self) -> &wgpu::Buffer {
        &self.counters
    }

    /// The merge load (`N_LOAD` u32: what the frame saw).
    pub fn load(&self) -> &wgpu::Buffer {
        &self.load
    }

    /// Zeroes the frame's totals and the merge load's frame words (write_buffer: takes effect
    /// at the frame's first submit).
    pub fn start_frame(&self, ctx: &Context) {
        ctx.queue.write_buffer(
            &self.counters,
            (C_FRAME_MERGES * 4) as u64,
            bytemuck::cast_slice(&[0u32; 4]),
        );
        ctx.queue
            .write_buffer(&self.load, 0, bytemuck::cast_slice(&[0u32; N_LOAD]));
    }

    /// Shape energy and marks (the marks phase).
    fn record_marks(&self, rec: &mut Recorder, live: &LiveBuffer) {
        let mark = MarkEntry::Mark;
        per_particle(&self.mark, &mut rec.pass(), mark, &self.binds.mark, live);
    }

    /// The cells to visit per colour, one cooperative dispatch per colour, then the compaction
    /// of the dead slots (the merge phase).
    fn record_merges(&self, rec: &mut Recorder, live: &LiveBuffer) {
        let b = &self.binds;
        rec.encoder().clear_buffer(&self.colour_count, 0, None);
        let mut pass = rec.pass();
        let cells = Dispatch::Threads(self.num_cells);
        let plan = [(&b.plan, 0)];
        self.plan
            .dispatch(&mut pass, PlanEntry::Cells, &plan, cells);
        let one = Dispatch::Groups(1);
        self.plan
            .dispatch(&mut pass, PlanEntry::Dispatches, &plan, one);
        for c in 0..self.n_colours {
            self.merge.dispatch(
                &mut pass,
                MergeEntry::Merge,
                &[(&b.merge, 0), (&b.colour, self.colours.offset(c))],
                Dispatch::Indirect(&self.merge_args, c as u64 * 16),
            );
        }
        self.scan.encode(&mut pass, 0);
        let totals = StatsEntry::Merges;
        self.stats
            .dispatch(&mut pass, totals, &[(&b.stats, 0)], one);
        per_particle(
            &self.compact,
            &mut pass,
            CompactEntry::Holes,
            &b.compact,
            live,
        );
        per_particle(
            &self.compact,
            &mut pass,
            CompactEntry::Move,
            &b.compact,
            live,
        );
    }

    /// The scan of the split marks, the new live state, children and level counts, and the new
    /// live state copied over `live` (the split phase).
    fn record_splits(&self, rec: &mut Recorder, live: &LiveBuffer) {
        let b = &self.binds;
        {
            let mut pass = rec.pass();
            self.scan.encode(&mut pass, 1);
            let totals = StatsEntry::Splits;
            let one = Dispatch::Groups(1);
            self.stats
                .dispatch(&mut pass, totals, &[(&b.stats, 0)], one);
            per_particle(&self.split, &mut pass, SplitEntry::Split, &b.split, live);
        }
        rec.encoder().copy_buffer_to_buffer(
            &self.counters,
            (C_LIVE * 4) as u64,
            live.buffer(),
            0,
            std::mem::size_of::<crate::gpu::live::Live>() as u64,
        );
    }

    /// The run's report from the read-back counters (`N_COUNTERS` u32).
    pub fn report(&self, c: &[u32]) -> AdaptiveReport {
        let n_levels = self.params.max_level as usize + 1;
        let per_level = c[C_LEVELS..C_LEVELS + n_levels].to_vec();
        AdaptiveReport {
            mass_units: mass_units(&per_level, self.params.max_level),
            per_level,
            splits: c[C_SPLITS],
            merges: c[C_MERGES],
            skipped_splits: c[C_SKIPPED],
            count: c[C_FINAL],
            next_id: c[C_NEXT_ID],
        }
    }

    /// The frame's totals from the read-back counters.
    pub fn frame_totals(c: &[u32]) -> FrameTotals {
        FrameTotals {
            merges: c[C_FRAME_MERGES],
            splits: c[C_FRAME_MERGES + 1],
            skipped_splits: c[C_FRAME_MERGES + 2],
        }
    }

    /// The largest loop count per invocation this device runs (`Prelude::loop_budget`).
    pub fn loop_budget(&self) -> u32 {
        self.loop_budget
    }

    /// Records and runs one split/merge on its own (its phases in the order of `sim::step`)
    /// and reads the counters back (tests and benchmarks; the simulation records the stage
    /// into its substeps instead).
    pub fn run(&self, ctx: &Context, live: &LiveBuffer) -> Result<AdaptiveReport> {
        self.start_frame(ctx);
        let mut rec = Recorder::new(ctx, None, None);
        self.record_marks(&mut rec, live);
        self.record_merges(&mut rec, live);
        self.record_splits(&mut rec, live);
        rec.submit();
        let mut rb = buffers::Readback::default();
        let counters = rb.add_array::<u32>(&self.counters, N_COUNTERS);
        let load = rb.add_array::<u32>(&self.load, N_LOAD);
        let data = rb.finish(ctx, ctx.device.create_command_encoder(&Default::default()))?;
        load_error(&data.get::<u32>(load), self.loop_budget)?;
        Ok(self.report(&data.get::<u32>(counters)))
    }
}

/// Records `entry` over the live particles.
fn per_particle<E: Entry>(
    program: &Program<E>,
    pass: &mut wgpu::ComputePass,
    entry: E,
    bind: &wgpu::BindGroup,
    live: &LiveBuffer,
) {
    program.dispatch(pass, entry, &[(bind, 0)], Dispatch::Live(live));
}

impl Stage for AdaptiveStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        let (cfg, h0) = (&setup.shot.config().adaptive, setup.shot.h0());
        Self::new(setup.ctx, cfg, setup.grid, h0, setup.buffers)
    }

    /// The marks, the merges or the splits; the cell table is stale afterwards (the next grid
    /// build re-sorts).
    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        match phase {
            Phase::Mark => self.record_marks(rec, sub.live),
            Phase::Merge => self.record_merges(rec, sub.live),
            Phase::Split => self.record_splits(rec, sub.live),
            other => return Err(crate::sim::stage::not_recorded("split and merge", other)),
        }
        Ok(())
    }

    fn device_bytes(&self) -> u64 {
        [
            &self.counters,
            &self.load,
            &self.cells,
            &self.colour_list,
            &self.colour_count,
            &self.merge_args,
        ]
        .iter()
        .map(|x| x.size())
        .sum::<u64>()
            + self.scan.device_bytes()
            + self.param_buf.size()
            + self.colour_map.size()
            + self.colours.size()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(dims: [u32; 3], px: bool, pz: bool) -> GridParams {
        GridParams::new(dims.map(|d| d as f64 * 0.1 + 0.01), 0.1, px, pz)
    }

    /// Every cell is in exactly one pass, and two cells of one pass are never within one cell
    /// of each other, wrap included (so their 27-cell neighbourhoods are disjoint).
    #[test]
    fn colour_passes_cover_once_and_never_touch() {
        for want in [
            [3, 3, 3],
            [4, 5, 7],
            [10, 4, 11],
            [5, 2, 8],
            [1, 1, 1],
            [6, 6, 6],
        ] {
            for (px, pz) in [(true, true), (false, false), (true, false)] {
                if (px && want[0] < 3) || (pz && want[2] < 3) {
                    continue;
                }
                let g = grid(want, px, pz);
                let dims = g.dims;
                assert_eq!(dims, want);
                let passes = colour_passes(&g);
                let mut seen = vec![0u32; g.num_cells as usize];
                for pass in &passes {
                    let cells: Vec<[i32; 3]> = (0..pass.cells()).map(|t| pass.cell(t)).collect();
                    for c in &cells {
                        seen[g.neighbor_cell(*c, [0, 0, 0]).unwrap() as usize] += 1;
                    }
                    let per = [px, false, pz];
                    for (a, ca) in cells.iter().enumerate() {
                        for cb in &cells[a + 1..] {
                            let far = (0..3).any(|ax| {
                                let n = dims[ax] as i32;
                                let mut dd = (ca[ax] - cb[ax]).abs();
                                if per[ax] {
                                    dd = dd.min(n - dd);
                                }
                                dd >= 3
                            });
                            assert!(far, "{dims:?} {ca:?} {cb:?} share a pass");
                        }
                    }
                }
                assert!(seen.iter().all(|&s| s == 1), "{dims:?}: {seen:?}");
            }
        }
        // A multiple of 3 needs exactly the 27 colours of Fig. 4.
        assert_eq!(colour_passes(&grid([6, 9, 3], true, true)).len(), 27);
    }

    /// The shader's colour of every cell is the colour pass that holds it.
    #[test]
    fn colour_map_matches_the_colour_passes() {
        for dims in [[3, 3, 3], [4, 5, 7], [10, 4, 11], [5, 2, 8], [1, 1, 1]] {
            for (px, pz) in [(true, true), (false, false), (true, false)] {
                if (px && dims[0] < 3) || (pz && dims[2] < 3) {
                    continue;
                }
                let g = grid(dims, px, pz);
                let map = ColourMap::of(&g);
                for (k, pass) in colour_passes(&g).iter().enumerate() {
                    for t in 0..pass.cells() {
                        let c = pass.cell(t).map(|v| v as u32);
                        assert_eq!(map.colour(c), k as u32, "{dims:?} {c:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn mass_units_by_level() {
        assert_eq!(mass_units(&[1, 2, 4], 2), 4 + 4 + 4);
        assert_eq!(level_mass_units(3, 3), 1);
    }
}
