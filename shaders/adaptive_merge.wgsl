// Adaptive stage 2: merge, one dispatch per colour of the grid (paper section 5.2.2, Fig. 4).
// A thread owns one cell and reads/writes only particles of the 27 cells around it; cells of
// one colour are >= 3 cells apart (also across periodic wraps), so no two threads of a pass
// touch the same particle and the result does not depend on thread scheduling.
// A cell's merge-marked slots are processed in rounds of `merge_round.len` (one dispatch each, in
// order): the same sequence as one pass over the cell, but each invocation stays within
// lavapipe's budget of 65535 loop iterations per invocation (llvmpipe silently ends longer
// loops). Rounds count marked slots, not slots: only a marked slot scans its neighbourhood, so a
// crowded cell with few marked particles needs no extra dispatches (~0.1 ms each here).
//!include shared/common.wgsl
//!include shared/adaptive.wgsl

// Cells of one colour: start + 3 * t per axis, t < count.
struct ColourPass {
    start: vec4<u32>,
    count: vec4<u32>,
}

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> params: AdaptiveParams;
@group(0) @binding(2) var<storage, read_write> pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> info: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read> cell_start: array<u32>;
@group(0) @binding(7) var<storage, read_write> flags: array<u32>;
@group(0) @binding(8) var<storage, read_write> load: array<atomic<u32>>;
@group(1) @binding(0) var<uniform> colour: ColourPass;
@group(2) @binding(0) var<uniform> merge_round: MergeRound;

// The marked slots of rank first .. first + len (in slot order) of every cell in this dispatch.
struct MergeRound {
    first: u32,
    len: u32,
    pad0: u32,
    pad1: u32,
}

// Nearest merge-marked partner of i on the same level within h (first found wins ties), or -1.
fn find_partner(i: u32, xi: vec3<f32>, level: u32, h: f32, c: vec3<i32>) -> i32 {
    var best = -1;
    var best_d2 = h * h;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                for (var k = cell_start[cell_entry(u32(n), grid)]; k < cell_start[cell_entry(u32(n) + 1u, grid)]; k++) {
                    if (k == i || flags[k] != FLAG_MERGE || info[k].y != level) { continue; }
                    let d = min_image(pos[k].xyz - xi, grid);
                    let d2 = dot(d, d);
                    if (d2 < best_d2) {
                        best_d2 = d2;
                        best = i32(k);
                    }
                }
            }
        }
    }
    return best;
}

// No live particle other than i and j closer than r to m.
fn merge_clear(i: u32, j: u32, m: vec3<f32>, r: f32, c: vec3<i32>) -> bool {
    let r2 = r * r;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                for (var k = cell_start[cell_entry(u32(n), grid)]; k < cell_start[cell_entry(u32(n) + 1u, grid)]; k++) {
                    if (k == i || k == j || (flags[k] & FLAG_DEAD) != 0u) { continue; }
                    let d = min_image(m - pos[k].xyz, grid);
                    if (dot(d, d) < r2) { return false; }
                }
            }
        }
    }
    return true;
}

@compute @workgroup_size(64)
fn adaptive_merge(@builtin(global_invocation_id) gid: vec3<u32>,
                  @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = thread_index(gid, nwg, 64u);
    let cnt = colour.count.xyz;
    if (t >= cnt.x * cnt.y * cnt.z) { return; }
    let tc = vec3<u32>(t % cnt.x, (t / cnt.x) % cnt.y, t / (cnt.x * cnt.y));
    let c = vec3<i32>(colour.start.xyz + 3u * tc);
    let d = vec3<i32>(grid.dims);
    let cell = u32((c.z * d.y + c.y) * d.x + c.x);
    // One thread pairs the particles of its cell in slot order (deterministic).
    let end = cell_start[cell_entry(cell + 1u, grid)];
    let last = merge_round.first + merge_round.len;
    var rank = 0u;
    for (var i = cell_start[cell_entry(cell, grid)]; i < end && rank < last; i++) {
        // Marked when the merge phase began: still MERGE, or MERGED / DEAD by a merge since
        // (only marked particles become either), so the ranks are the same in every round.
        let f = flags[i];
        if ((f & (FLAG_MERGE | FLAG_MERGED | FLAG_DEAD)) == 0u) { continue; }
        rank++;
        if (rank <= merge_round.first || f != FLAG_MERGE) { continue; }
        let level = info[i].y;
        let xi = pos[i].xyz;
        let best = find_partner(i, xi, level, level_radius(params.h0, level), c);
        if (best < 0) { continue; }
        let j = u32(best);
        // Equal masses on a level: the midpoint is the mass-weighted centre.
        let m = wrap_pos(xi + 0.5 * min_image(pos[j].xyz - xi, grid), grid);
        let r = params.min_distance * level_radius(params.h0, level - 1u);
        if (!merge_clear(i, j, m, r, c)) { continue; }
        pos[i] = vec4<f32>(m, pos[i].w);
        vel[i] = 0.5 * (vel[i] + vel[j]);
        thermo[i] = 0.5 * (thermo[i] + thermo[j]);
        // The older (smaller) id survives, so split-then-merge gives the original id back.
        info[i] = vec2<u32>(min(info[i].x, info[j].x), level - 1u);
        flags[i] = FLAG_MERGED;
        flags[j] = FLAG_DEAD;
    }
}

// Largest cell occupancy (load[0]), 27-cell neighbourhood (load[1]) and count of merge-marked
// particles in a cell (load[2]): the host sizes the merge rounds from them.
@compute @workgroup_size(64)
fn cell_load(@builtin(global_invocation_id) gid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let c = thread_index(gid, nwg, 64u);
    if (c >= grid.num_cells) { return; }
    let d = grid.dims;
    let cc = vec3<i32>(vec3<u32>(c % d.x, (c / d.x) % d.y, c / (d.x * d.y)));
    var nb = 0u;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(cc, vec3<i32>(dx, dy, dz), grid);
                if (n >= 0) { nb += cell_start[cell_entry(u32(n) + 1u, grid)] - cell_start[cell_entry(u32(n), grid)]; }
            }
        }
    }
    let begin = cell_start[cell_entry(c, grid)];
    let end = cell_start[cell_entry(c + 1u, grid)];
    var marked = 0u;
    for (var k = begin; k < end; k++) { marked += u32(flags[k] == FLAG_MERGE); }
    atomicMax(&load[0], end - begin);
    atomicMax(&load[1], nb);
    atomicMax(&load[2], marked);
}
