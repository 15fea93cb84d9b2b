// Adaptive stage 2: merge (paper section 5.2.2, Fig. 4), one dispatch per colour of the grid.
// A workgroup owns one cell of the colour that holds merge-marked particles (the lists
// adaptive_plan.wgsl builds) and reads/writes only particles of the 27 cells around it; cells of
// one colour are >= 3 cells apart (also across periodic wraps), so no two workgroups of a pass
// touch the same particle and the result does not depend on scheduling. Within the cell, the
// slots are merged in slot order, one after the other, exactly as one thread walking the cell
// would (the f64 mirror does): for each marked slot the workgroup's threads share the scan of
// the 27-cell neighbourhood (thread t takes every WG_PARTICLES-th candidate) and reduce to the
// nearest partner (ties: the first in neighbourhood order) and to whether the merged particle
// has room; thread 0 writes the merge. Sharing the scans keeps each invocation's loops far
// below lavapipe's budget (llvmpipe silently ends an invocation's loops after 65535 iterations
// in total), which adaptive_plan.wgsl checks per cell.
//!include shared/common.wgsl
//!include shared/adaptive.wgsl

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> params: AdaptiveParams;
@group(0) @binding(2) var<storage, read_write> pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> info: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read> cell_start: array<u32>;
@group(0) @binding(7) var<storage, read_write> flags: array<u32>;
// The cells to merge, colour by colour (colour c's list starts at colour_list[c].x), and how
// many each colour has.
@group(0) @binding(8) var<storage, read> cells: array<u32>;
@group(0) @binding(9) var<storage, read> colour_list: array<vec4<u32>>;
@group(0) @binding(10) var<storage, read> colour_count: array<u32>;
@group(1) @binding(0) var<uniform> colour: MergeColour;

// The colour of one merge dispatch.
struct MergeColour {
    index: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

const NONE: u32 = 0xffffffffu;

// This workgroup's cell, the 27 neighbour cells' slot ranges in neighbourhood order (empty
// outside a walled axis) and their prefix counts, the slot being merged, and the reductions.
var<workgroup> wg_cell: u32;
var<workgroup> wg_begin: u32;
var<workgroup> wg_end: u32;
var<workgroup> nb_start: array<u32, 27>;
var<workgroup> nb_pre: array<u32, 28>;
var<workgroup> wg_flag: u32;
// The reductions, by workgroup atomics (3 barriers where a tree over the threads takes 12): the
// nearest partner's squared distance (f32 bits: for d2 >= 0 they order as the values), the
// lowest neighbourhood order at that distance, its slot, and whether the midpoint is blocked.
var<workgroup> wg_d2: atomic<u32>;
var<workgroup> wg_order: atomic<u32>;
var<workgroup> wg_partner: u32;
var<workgroup> wg_blocked: atomic<u32>;

// The neighbourhood slot of this thread's n-th candidate in neighbour cell kc, or NONE: thread t
// takes the candidates whose neighbourhood order p = nb_pre[kc] + (k - nb_start[kc]) is
// t mod WG_PARTICLES.
fn first_candidate(kc: u32, t: u32) -> u32 {
    let skip = (t + WG_PARTICLES - nb_pre[kc] % WG_PARTICLES) % WG_PARTICLES;
    return nb_start[kc] + skip;
}

// The slot i being merged, its position and level.
struct Merging {
    i: u32,
    x: vec3<f32>,
    level: u32,
}
// This thread's nearest partner so far: squared distance, neighbourhood order, slot.
struct Nearest {
    d2: f32,
    order: u32,
    slot: u32,
}
// Candidate k of neighbour cell kc as i's partner: merge-marked, on i's level, nearer than the
// best so far (ties: the first in this thread's neighbourhood order). Never stops the walk.
fn nearest_pair(a: ptr<function, Nearest>, me: Merging, kc: u32, k: u32) -> bool {
    if (k == me.i || flags[k] != FLAG_MERGE || info[k].y != me.level) { return false; }
    let dk = min_image(pos[k].xyz - me.x, grid);
    let d2 = dot(dk, dk);
    if (d2 < (*a).d2) {
        (*a).d2 = d2;
        (*a).order = nb_pre[kc] + (k - nb_start[kc]);
        (*a).slot = k;
    }
    return false;
}
//!walk nearest_walk

// The merge of slots i and j at midpoint m, and how close another particle may come to it
// (squared).
struct Product {
    i: u32,
    j: u32,
    m: vec3<f32>,
    r2: f32,
}
// Whether live candidate k other than i and j is too close to the midpoint (stops the walk).
fn room_blocked(me: Product, k: u32) -> bool {
    if (k == me.i || k == me.j || (flags[k] & FLAG_DEAD) != 0u) { return false; }
    let dk = min_image(me.m - pos[k].xyz, grid);
    return dot(dk, dk) < me.r2;
}
//!walk room_walk

@compute @workgroup_size(WG_PARTICLES)
fn adaptive_merge(@builtin(workgroup_id) wid: vec3<u32>,
                  @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    if (t == 0u) {
        wg_cell = NONE;
        if (g < colour_count[colour.index]) { wg_cell = cells[colour_list[colour.index].x + g]; }
    }
    let cell = workgroupUniformLoad(&wg_cell);
    if (cell == NONE) { return; }
    let d = grid.dims;
    let c = vec3<i32>(vec3<u32>(cell % d.x, (cell / d.x) % d.y, cell / (d.x * d.y)));
    if (t < 27u) {
        let e = cell_entries(c, t, grid);
        var start = 0u;
        var len = 0u;
        if (e.x != e.y) {
            start = cell_start[e.x];
            len = cell_start[e.y] - start;
        }
        nb_start[t] = start;
        nb_pre[t + 1u] = len;
    }
    if (t == 0u) {
        wg_begin = cell_start[cell_entry(cell, grid)];
        wg_end = cell_start[cell_entry(cell + 1u, grid)];
    }
    workgroupBarrier();
    if (t == 0u) {
        nb_pre[0] = 0u;
        for (var k = 1u; k <= 27u; k++) { nb_pre[k] = nb_pre[k] + nb_pre[k - 1u]; }
    }
    let begin = workgroupUniformLoad(&wg_begin);
    let end = workgroupUniformLoad(&wg_end);
    for (var i = begin; i < end; i++) {
        if (t == 0u) {
            wg_flag = flags[i];
            atomicStore(&wg_d2, NONE);
            atomicStore(&wg_order, NONE);
            wg_partner = NONE;
            atomicStore(&wg_blocked, 0u);
        }
        // still only merge-marked: not merged into, nor the product of a merge, in this run
        if (workgroupUniformLoad(&wg_flag) != FLAG_MERGE) { continue; }
        let level = info[i].y;
        let xi = pos[i].xyz;
        let h = level_radius(params.h0, level);
        // Nearest merge-marked partner on the same level within h.
        var best = Nearest(h * h, NONE, NONE);
        _ = nearest_walk(&best, Merging(i, xi, level), t);
        if (best.order != NONE) { atomicMin(&wg_d2, bitcast<u32>(best.d2)); }
        workgroupBarrier();
        if (best.order != NONE && bitcast<u32>(best.d2) == atomicLoad(&wg_d2)) {
            atomicMin(&wg_order, best.order);
        }
        workgroupBarrier();
        // neighbourhood orders are distinct: one thread holds the winner
        if (best.order != NONE && best.order == atomicLoad(&wg_order)) { wg_partner = best.slot; }
        let j = workgroupUniformLoad(&wg_partner);
        if (j == NONE) {
            continue;
        }
        // Equal masses on a level: the midpoint is the mass-weighted centre; it needs room.
        let m = wrap_pos(xi + 0.5 * min_image(pos[j].xyz - xi, grid), grid);
        let r = params.min_distance * level_radius(params.h0, level - 1u);
        if (room_walk(Product(i, j, m, r * r), t)) { atomicOr(&wg_blocked, 1u); }
        workgroupBarrier();
        if (t == 0u && atomicLoad(&wg_blocked) == 0u) {
            pos[i] = vec4<f32>(m, pos[i].w);
            vel[i] = 0.5 * (vel[i] + vel[j]);
            thermo[i] = 0.5 * (thermo[i] + thermo[j]);
            // The older (smaller) id survives, so split-then-merge gives the original id back.
            info[i] = vec2<u32>(min(info[i].x, info[j].x), level - 1u);
            flags[i] = FLAG_MERGED;
            flags[j] = FLAG_DEAD;
        }
        // the next slot's scans see this merge
        storageBarrier();
        workgroupBarrier();
    }
}
