//! Adaptive particles (paper section 5.2): shape energy, split and merge on the GPU.
//!
//! A self-contained stage over the particle buffers of docs/ARCHITECTURE.md (cell-ordered, with
//! the cell table of the last grid build). One [`AdaptiveStage::run`]:
//! 1. `adaptive_mark`: E = kp (1 - exp(-kc w)) into `thermo.w`; merge marks (E < beta, l > 0);
//!    split marks (E > alpha, l < max_level) where both children fit (min_distance);
//! 2. `adaptive_merge`, one dispatch per grid colour: pairs of marked same-level neighbours
//!    become one particle of level l-1 in the lower slot, the other slot dies;
//! 3. scan of dead flags, `compact_holes` + `compact_move`: in-place deterministic compaction;
//! 4. scan of split marks, `adaptive_split`: children appended after the live range, up to the
//!    capacity (excess splits skipped and counted);
//! 5. `count_levels` and a read-back of a few counters: [`AdaptiveReport`].
//!
//! Marks and the split room check read one snapshot (before any merge), so neither depends on
//! the other's outcome. The f64 mirror is `sim::reference::adaptive`.
use std::time::Instant;

use crate::config::AdaptiveConfig;
use crate::error::{Error, Result};
use crate::gpu::{buffers, shaders, Context};
use crate::sim::grid_params::GridParams;

/// Levels the counters buffer has room for (`MAX_LEVELS` in shaders/shared/adaptive.wgsl).
pub const MAX_LEVELS: u32 = 24;
/// Largest `max_level`: mass units 2^max_level per level-0 particle stay far inside u64 sums.
pub const MAX_LEVEL_LIMIT: u32 = 20;
/// Largest `min_distance` for which the 27 cells around a merging cell hold every particle the
/// room check needs: |midpoint - x_i| < h_l / 2 <= 2^(-1/3) L / 2 and h_new <= L.
pub const MAX_MIN_DISTANCE: f64 = 0.6;

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
const N_COUNTERS: usize = C_LEVELS + MAX_LEVELS as usize;

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
    /// Validated parameters of a shot (count and next_id are set per run).
    pub fn new(cfg: &AdaptiveConfig, h0: f64, capacity: u32) -> Result<Self> {
        let bad = |key: &str, msg: String| Err(Error::Config(format!("adaptive.{key}: {msg}")));
        if cfg.max_level > MAX_LEVEL_LIMIT {
            return bad(
                "max_level",
                format!("{} is above the limit {MAX_LEVEL_LIMIT}", cfg.max_level),
            );
        }
        let ordered = cfg.merge_threshold < cfg.split_threshold;
        if !ordered {
            return bad(
                "merge_threshold",
                format!(
                    "must be below split_threshold ({} >= {})",
                    cfg.merge_threshold, cfg.split_threshold
                ),
            );
        }
        if !(0.0..=MAX_MIN_DISTANCE).contains(&cfg.min_distance) {
            return bad(
                "min_distance",
                format!("{} is outside [0, {MAX_MIN_DISTANCE}]", cfg.min_distance),
            );
        }
        if cfg.split_offset.is_nan() || cfg.split_offset <= 0.0 || cfg.split_offset > 0.5 {
            return bad(
                "split_offset",
                format!("{} is outside (0, 0.5]", cfg.split_offset),
            );
        }
        if !(cfg.kp.is_finite() && cfg.kc.is_finite()) {
            return bad("kp", "kp and kc must be finite".into());
        }
        if !h0.is_finite() || h0 <= 0.0 {
            return Err(Error::Config(format!(
                "domain: kernel radius {h0} must be positive"
            )));
        }
        Ok(Self {
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
        })
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

/// Wall time of the two halves of a run (ms; each phase ends with a GPU wait).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AdaptivePhaseMs {
    /// Marks with the split room check, the split scan and the split writes.
    pub split: f64,
    /// Coloured merge passes and the compaction.
    pub merge: f64,
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
    pub phase_ms: AdaptivePhaseMs,
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

/// The caller's buffers (docs/ARCHITECTURE.md): particle arrays of length `capacity`, cell
/// ordered, and the cell table + grid uniform of their last build.
pub struct AdaptiveBuffers<'a> {
    pub grid: &'a wgpu::Buffer,
    pub pos: &'a wgpu::Buffer,
    pub vel: &'a wgpu::Buffer,
    pub thermo: &'a wgpu::Buffer,
    pub info: &'a wgpu::Buffer,
    pub cell_start: &'a wgpu::Buffer,
}

/// One level of the recursive prefix scan.
struct ScanLevel {
    out: wgpu::Buffer,
    /// Params per scan (dead flags, split flags).
    params: [wgpu::Buffer; 2],
    blocks: [wgpu::BindGroup; 2],
    /// Adds the next level's scanned sums back (absent on the last level).
    add: Option<[wgpu::BindGroup; 2]>,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ScanParams {
    n: u32,
    mask: u32,
    pad: [u32; 2],
}

struct Pipelines {
    mark: wgpu::ComputePipeline,
    merge: wgpu::ComputePipeline,
    cell_load: wgpu::ComputePipeline,
    scan_blocks: wgpu::ComputePipeline,
    scan_add: wgpu::ComputePipeline,
    holes: wgpu::ComputePipeline,
    moves: wgpu::ComputePipeline,
    split: wgpu::ComputePipeline,
    totals_merge: wgpu::ComputePipeline,
    totals_split: wgpu::ComputePipeline,
    levels: wgpu::ComputePipeline,
}

/// The GPU split/merge stage with its scratch buffers (about 12 bytes per particle of capacity).
pub struct AdaptiveStage {
    params: AdaptiveParams,
    capacity: u32,
    pipes: Pipelines,
    params_buf: wgpu::Buffer,
    flags: wgpu::Buffer,
    hole_index: wgpu::Buffer,
    counters: wgpu::Buffer,
    /// Largest cell occupancy, 27-cell neighbourhood and merge-marked count (sizes the rounds).
    load: wgpu::Buffer,
    num_cells: u32,
    scan: Vec<ScanLevel>,
    colours: Vec<(ColourPass, wgpu::BindGroup)>,
}

const SCAN_BLOCK: u32 = 256;

fn bind(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    group: u32,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let at: Vec<(u32, &wgpu::Buffer)> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| (i as u32, *b))
        .collect();
    bind_at(device, pipeline, group, &at)
}

/// A bind group of `(binding, buffer)`: automatic layouts hold only what an entry point uses.
fn bind_at(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    group: u32,
    buffers: &[(u32, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: *i,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(group),
        entries: &entries,
    })
}

/// Records a dispatch of `groups` workgroups, folded into 2D past the 65535 limit (shaders
/// linearise with `num_workgroups` and bounds-check).
fn dispatch(
    pass: &mut wgpu::ComputePass,
    pipeline: &wgpu::ComputePipeline,
    groups: &[&wgpu::BindGroup],
    n_groups: u32,
) {
    if n_groups == 0 {
        return;
    }
    pass.set_pipeline(pipeline);
    for (i, g) in groups.iter().enumerate() {
        pass.set_bind_group(i as u32, Some(*g), &[]);
    }
    let x = n_groups.min(65535);
    pass.dispatch_workgroups(x, n_groups.div_ceil(x), 1);
}

/// Loop iterations one shader invocation may run: llvmpipe (lavapipe) ends every loop of an
/// invocation after 65535 iterations in total, silently; stay below with a margin.
pub const LOOP_BUDGET: u64 = 60_000;

/// Slot range of one merge round (`MergeRound` in adaptive_merge.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MergeRound {
    pub first: u32,
    pub len: u32,
    pub pad: [u32; 2],
}

/// Rounds that split every cell's merge loop so one invocation stays within [`LOOP_BUDGET`]:
/// a round walks at most the cell's `max_occupancy` slots and merges up to `len` marked ones,
/// each at most two scans of its 27-cell neighbourhood (`max_neighbourhood` particles) plus the
/// cell loops. Rounds count marked slots (`max_marked` in the fullest cell) and run in order, so
/// the result is the one of a single pass over each cell (the mirror's).
pub fn merge_rounds(
    max_occupancy: u32,
    max_marked: u32,
    max_neighbourhood: u32,
) -> Result<Vec<MergeRound>> {
    let per_slot = 2 * max_neighbourhood as u64 + 100;
    let len = LOOP_BUDGET.saturating_sub(max_occupancy as u64) / per_slot;
    if len == 0 {
        return Err(Error::Runtime(format!(
            "adaptive: {max_neighbourhood} particles around one grid cell are more than a merge \
             pass can scan; lower the particle density or max_level"
        )));
    }
    let len = len.min(u32::MAX as u64) as u32;
    Ok((0..max_marked.div_ceil(len))
        .map(|r| MergeRound {
            first: r * len,
            len,
            pad: [0; 2],
        })
        .collect())
}

fn wait(ctx: &Context) -> Result<()> {
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .map_err(|e| Error::Runtime(format!("GPU poll failed: {e}")))
}

impl AdaptiveStage {
    /// Builds the stage for particle arrays of `capacity` on `grid` (its host copy: the merge
    /// colours follow its dims), kernel radius `h0` of level 0.
    pub fn new(
        ctx: &Context,
        cfg: &AdaptiveConfig,
        grid: &GridParams,
        h0: f64,
        capacity: u32,
    ) -> Result<Self> {
        let params = AdaptiveParams::new(cfg, h0, capacity)?;
        if let Some(edge) = grid
            .cell_size
            .iter()
            .find(|&&e| e < h0 as f32 * (1.0 - 1e-6))
        {
            return Err(Error::Config(format!(
                "domain: grid cells ({edge}) are smaller than the kernel radius {h0}"
            )));
        }
        if (grid.periodic_x() && grid.dims[0] < 3) || (grid.periodic_z() && grid.dims[2] < 3) {
            return Err(Error::Config(
                "domain: a periodic axis needs at least 3 grid cells".into(),
            ));
        }
        let d = &ctx.device;
        let pipes = Pipelines {
            mark: shaders::compute_pipeline(d, "adaptive_mark.wgsl", "adaptive_mark")?,
            merge: shaders::compute_pipeline(d, "adaptive_merge.wgsl", "adaptive_merge")?,
            cell_load: shaders::compute_pipeline(d, "adaptive_merge.wgsl", "cell_load")?,
            scan_blocks: shaders::compute_pipeline(d, "adaptive_scan.wgsl", "scan_blocks")?,
            scan_add: shaders::compute_pipeline(d, "adaptive_scan.wgsl", "add_block_offsets")?,
            holes: shaders::compute_pipeline(d, "adaptive_compact.wgsl", "compact_holes")?,
            moves: shaders::compute_pipeline(d, "adaptive_compact.wgsl", "compact_move")?,
            split: shaders::compute_pipeline(d, "adaptive_split.wgsl", "adaptive_split")?,
            totals_merge: shaders::compute_pipeline(d, "adaptive_stats.wgsl", "totals_merge")?,
            totals_split: shaders::compute_pipeline(d, "adaptive_stats.wgsl", "totals_split")?,
            levels: shaders::compute_pipeline(d, "adaptive_stats.wgsl", "count_levels")?,
        };
        let cap = capacity.max(1) as usize;
        let params_buf = buffers::uniform_init(d, "adaptive params", &params);
        let flags = buffers::storage_zeroed::<u32>(d, "adaptive flags", cap);
        let hole_index = buffers::storage_zeroed::<u32>(d, "adaptive holes", cap);
        let counters = buffers::storage_zeroed::<u32>(d, "adaptive counters", N_COUNTERS);
        let load = buffers::storage_zeroed::<u32>(d, "adaptive cell load", 4);

        // Scan levels: lengths cap, cap/256, ... down to one block.
        let mut lens = vec![cap as u32];
        while *lens.last().unwrap() > SCAN_BLOCK {
            lens.push(lens.last().unwrap().div_ceil(SCAN_BLOCK));
        }
        let outs: Vec<wgpu::Buffer> = lens
            .iter()
            .map(|&n| buffers::storage_zeroed::<u32>(d, "adaptive scan", n as usize))
            .collect();
        let sums: Vec<wgpu::Buffer> = lens
            .iter()
            .map(|&n| {
                buffers::storage_zeroed::<u32>(
                    d,
                    "adaptive scan sums",
                    n.div_ceil(SCAN_BLOCK) as usize,
                )
            })
            .collect();
        let zero = ScanParams {
            n: 0,
            mask: 0,
            pad: [0; 2],
        };
        let mut scan = Vec::new();
        for k in 0..lens.len() {
            let input = if k == 0 { &flags } else { &sums[k - 1] };
            let params: [wgpu::Buffer; 2] =
                std::array::from_fn(|_| buffers::uniform_init(d, "adaptive scan params", &zero));
            let blocks = std::array::from_fn(|s| {
                bind(
                    d,
                    &pipes.scan_blocks,
                    0,
                    &[&params[s], input, &outs[k], &sums[k]],
                )
            });
            let add = (k + 1 < lens.len()).then(|| {
                std::array::from_fn(|s| {
                    bind(d, &pipes.scan_add, 0, &[&params[s], &outs[k + 1], &outs[k]])
                })
            });
            scan.push(ScanLevel {
                out: outs[k].clone(),
                params,
                blocks,
                add,
            });
        }
        let colours = colour_passes(grid)
            .into_iter()
            .map(|c| {
                let buf = buffers::uniform_init(d, "adaptive colour", &c);
                let group = bind(d, &pipes.merge, 1, &[&buf]);
                (c, group)
            })
            .collect();
        Ok(Self {
            params,
            capacity,
            pipes,
            params_buf,
            flags,
            hole_index,
            counters,
            load,
            num_cells: grid.num_cells,
            scan,
            colours,
        })
    }

    pub fn params(&self) -> &AdaptiveParams {
        &self.params
    }

    pub fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Exclusive scan of `flags & mask` over the first `n` particles into `scan[0].out`.
    fn record_scan(&self, ctx: &Context, pass: &mut wgpu::ComputePass, which: usize, n: u32) {
        let mask = [FLAG_DEAD, FLAG_SPLIT][which];
        let mut ns = vec![n];
        while *ns.last().unwrap() > SCAN_BLOCK {
            ns.push(ns.last().unwrap().div_ceil(SCAN_BLOCK));
        }
        for (k, &nk) in ns.iter().enumerate() {
            let p = ScanParams {
                n: nk,
                mask: if k == 0 { mask } else { 0 },
                pad: [0; 2],
            };
            ctx.queue
                .write_buffer(&self.scan[k].params[which], 0, bytemuck::bytes_of(&p));
            dispatch(
                pass,
                &self.pipes.scan_blocks,
                &[&self.scan[k].blocks[which]],
                nk.div_ceil(SCAN_BLOCK),
            );
        }
        for k in (0..ns.len() - 1).rev() {
            let add = self.scan[k]
                .add
                .as_ref()
                .expect("level below the top has an add");
            dispatch(
                pass,
                &self.pipes.scan_add,
                &[&add[which]],
                ns[k].div_ceil(SCAN_BLOCK),
            );
        }
    }

    /// Runs marks, merges, compaction and splits on the first `count` particles; new ids start
    /// at `next_id`. Returns the new count and the stats (the particle arrays are updated in
    /// place; the cell table is stale afterwards, the next grid build re-sorts).
    /// The deepest level a split may reach.
    pub fn max_level(&self) -> u32 {
        self.params.max_level
    }

    pub fn run(
        &self,
        ctx: &Context,
        bufs: &AdaptiveBuffers,
        count: u32,
        next_id: u32,
    ) -> Result<AdaptiveReport> {
        if count > self.capacity {
            return Err(Error::InvalidInput(format!(
                "adaptive: {count} particles exceed the capacity {}",
                self.capacity
            )));
        }
        if next_id.checked_add(self.capacity).is_none() {
            return Err(Error::Runtime(format!(
                "adaptive: particle ids exhausted (next id {next_id})"
            )));
        }
        let d = &ctx.device;
        let p = &self.pipes;
        let params = AdaptiveParams {
            count,
            next_id,
            ..self.params
        };
        ctx.queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&params));
        let scan0 = &self.scan[0].out;
        let mark = bind(
            d,
            &p.mark,
            0,
            &[
                bufs.grid,
                &self.params_buf,
                bufs.pos,
                bufs.thermo,
                bufs.info,
                bufs.cell_start,
                &self.flags,
            ],
        );
        let merge = bind(
            d,
            &p.merge,
            0,
            &[
                bufs.grid,
                &self.params_buf,
                bufs.pos,
                bufs.vel,
                bufs.thermo,
                bufs.info,
                bufs.cell_start,
                &self.flags,
            ],
        );
        let holes = bind(
            d,
            &p.holes,
            0,
            &[
                &self.params_buf,
                &self.counters,
                scan0,
                &self.flags,
                &self.hole_index,
            ],
        );
        let moves = bind(
            d,
            &p.moves,
            0,
            &[
                &self.params_buf,
                &self.counters,
                scan0,
                &self.flags,
                &self.hole_index,
                bufs.pos,
                bufs.vel,
                bufs.thermo,
                bufs.info,
            ],
        );
        let split = bind(
            d,
            &p.split,
            0,
            &[
                bufs.grid,
                &self.params_buf,
                &self.counters,
                scan0,
                &self.flags,
                bufs.pos,
                bufs.vel,
                bufs.thermo,
                bufs.info,
            ],
        );
        let totals = [&self.params_buf, &self.counters, scan0, &self.flags];
        let totals_merge = bind(d, &p.totals_merge, 0, &totals);
        let totals_split = bind(d, &p.totals_split, 0, &totals);
        let levels = bind_at(d, &p.levels, 0, &[(1, &self.counters), (4, bufs.info)]);
        let groups = count.div_ceil(256);

        // Phase 1 (split): marks and the split room check; the cell load for the merge rounds.
        let cell_load = bind_at(
            d,
            &p.cell_load,
            0,
            &[
                (0, bufs.grid),
                (6, bufs.cell_start),
                (7, &self.flags),
                (8, &self.load),
            ],
        );
        ctx.queue.write_buffer(&self.load, 0, &[0u8; 16]);
        let t0 = Instant::now();
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            dispatch(&mut pass, &p.mark, &[&mark], groups);
            dispatch(
                &mut pass,
                &p.cell_load,
                &[&cell_load],
                self.num_cells.div_ceil(64),
            );
        }
        ctx.queue.submit([enc.finish()]);
        wait(ctx)?;
        let t1 = Instant::now();

        // Phase 2 (merge): coloured passes in rounds, then the compaction of the dead slots.
        let load: Vec<u32> = buffers::read_back(d, &ctx.queue, &self.load, 3)?;
        let rounds = merge_rounds(load[0], load[2], load[1])?;
        let round_groups: Vec<wgpu::BindGroup> = rounds
            .iter()
            .map(|r| {
                let buf = buffers::uniform_init(d, "adaptive merge round", r);
                bind(d, &p.merge, 2, &[&buf])
            })
            .collect();
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            if count > 0 {
                for (c, cg) in &self.colours {
                    for rg in &round_groups {
                        dispatch(
                            &mut pass,
                            &p.merge,
                            &[&merge, cg, rg],
                            c.cells().div_ceil(64),
                        );
                    }
                }
            }
            self.record_scan(ctx, &mut pass, 0, count);
            dispatch(&mut pass, &p.totals_merge, &[&totals_merge], 1);
            dispatch(&mut pass, &p.holes, &[&holes], groups);
            dispatch(&mut pass, &p.moves, &[&moves], groups);
        }
        ctx.queue.submit([enc.finish()]);
        wait(ctx)?;
        let t2 = Instant::now();

        // Phase 3 (split): scan of the split marks, children, per-level counts.
        let mut enc = d.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            self.record_scan(ctx, &mut pass, 1, count);
            dispatch(&mut pass, &p.totals_split, &[&totals_split], 1);
            dispatch(&mut pass, &p.split, &[&split], groups);
            let upper = (count as u64 * 2).min(self.capacity as u64) as u32;
            dispatch(&mut pass, &p.levels, &[&levels], upper.div_ceil(256));
        }
        ctx.queue.submit([enc.finish()]);
        wait(ctx)?;
        let t3 = Instant::now();

        let c: Vec<u32> = buffers::read_back(d, &ctx.queue, &self.counters, N_COUNTERS)?;
        let n_levels = self.params.max_level as usize + 1;
        let per_level = c[C_LEVELS..C_LEVELS + n_levels].to_vec();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        Ok(AdaptiveReport {
            mass_units: mass_units(&per_level, self.params.max_level),
            per_level,
            splits: c[C_SPLITS],
            merges: c[C_MERGES],
            skipped_splits: c[C_SKIPPED],
            count: c[C_FINAL],
            next_id: c[C_NEXT_ID],
            phase_ms: AdaptivePhaseMs {
                split: ms(t0, t1) + ms(t2, t3),
                merge: ms(t1, t2),
            },
        })
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

    #[test]
    fn params_validation_rejects_bad_config() {
        let ok = AdaptiveConfig::default();
        assert!(AdaptiveParams::new(&ok, 0.1, 10).is_ok());
        let breakers: [fn(&mut AdaptiveConfig); 5] = [
            |c: &mut AdaptiveConfig| c.max_level = 40,
            |c: &mut AdaptiveConfig| c.merge_threshold = c.split_threshold,
            |c: &mut AdaptiveConfig| c.min_distance = 0.9,
            |c: &mut AdaptiveConfig| c.split_offset = 0.0,
            |c: &mut AdaptiveConfig| c.kc = f64::NAN,
        ];
        for f in breakers {
            let mut c = ok.clone();
            f(&mut c);
            assert!(matches!(
                AdaptiveParams::new(&c, 0.1, 10),
                Err(Error::Config(_))
            ));
        }
    }

    #[test]
    fn merge_rounds_cover_the_fullest_cell_within_budget() {
        assert!(merge_rounds(0, 0, 0).unwrap().is_empty());
        assert!(merge_rounds(90, 0, 1000).unwrap().is_empty());
        for (occ, marked, nb) in [(1, 1, 1), (300, 300, 300), (64, 5, 1728), (100, 90, 29_000)] {
            let r = merge_rounds(occ, marked, nb).unwrap();
            let len = r[0].len as u64;
            assert!(occ as u64 + len * (2 * nb as u64 + 100) <= LOOP_BUDGET);
            assert_eq!(
                r.iter().map(|x| x.first).collect::<Vec<_>>(),
                (0..r.len() as u32)
                    .map(|k| k * r[0].len)
                    .collect::<Vec<_>>()
            );
            assert!(r.last().unwrap().first + r[0].len >= marked);
        }
        // a few marked particles in a crowded neighbourhood: one round, not one per slot range
        assert_eq!(merge_rounds(90, 5, 1000).unwrap().len(), 1);
        assert!(matches!(
            merge_rounds(10, 10, 40_000),
            Err(Error::Runtime(_))
        ));
    }

    #[test]
    fn mass_units_by_level() {
        assert_eq!(mass_units(&[1, 2, 4], 2), 4 + 4 + 4);
        assert_eq!(level_mass_units(3, 3), 1);
    }
}
