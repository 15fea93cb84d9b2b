// Adaptive stage 2a: which cells the merge visits. `merge_cells` (a thread per cell) appends
// every cell holding a merge-marked particle with a merge-marked partner in reach (`may_merge`)
// to its colour's list (the order within a list does
// not matter: cells of one colour are independent) and checks that the cooperative merge of
// adaptive_merge.wgsl stays within the device's loop budget for it; `merge_dispatch` (one thread)
// writes each colour's indirect dispatch arguments: one workgroup per listed cell. The host
// never reads any of it back inside a frame. (Its own file: the merge dispatches read
// `merge_args` as indirect arguments, which must not be bound writable in the same dispatch.)
// Mirror: src/sim/reference/adaptive_plan.rs.
//!include shared/common.wgsl
//!include shared/adaptive.wgsl

// Per axis: cells below `split` take class x mod 3, the ones at or past it (the last one or two
// slabs of a periodic axis whose cell count is not a multiple of 3) classes of their own; and
// the number of classes. Colour = (class_z * classes_y + class_y) * classes_x + class_x, the
// order of sim::adaptive::colour_passes.
struct ColourMap {
    split: vec4<u32>,
    classes: vec4<u32>,
}

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> colour_map: ColourMap;
@group(0) @binding(2) var<storage, read> cell_start: array<u32>;
@group(0) @binding(3) var<storage, read> flags: array<u32>;
@group(0) @binding(4) var<storage, read_write> cells: array<u32>;
// (list start, cells of the colour, 0, 0) per colour
@group(0) @binding(5) var<storage, read> colour_list: array<vec4<u32>>;
// listed cells per colour (zeroed before merge_cells)
@group(0) @binding(6) var<storage, read_write> colour_count: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read_write> merge_args: array<vec4<u32>>;
// words 0..4 what the frame saw (the host zeroes them when a frame starts): an error (1: a cell
// whose merge would run past the loop budget), the largest loop estimate, the most listed cells
@group(0) @binding(8) var<storage, read_write> load: array<atomic<u32>>;
@group(0) @binding(9) var<uniform> params: AdaptiveParams;
@group(0) @binding(10) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read> info: array<vec2<u32>>;

// Loop trips `may_merge` takes at most before it lists a cell unchecked (well within the loop
// budget with merge_cells' own walks).
const PARTNER_SCAN_CAP: u32 = 8192u;

// The slots [begin, end) of the cell whose merges are in question.
struct Slots {
    begin: u32,
    end: u32,
}

// Whether merge-marked candidate k has a merge-marked partner among the cell's slots on its
// level closer than h (adaptive_merge's partner test, the same f32 expression), or the walk has
// taken PARTNER_SCAN_CAP loop trips (`tested`): either stops it.
fn partner_found(tested: ptr<function, u32>, me: Slots, k: u32) -> bool {
    *tested += 1u;
    if (*tested > PARTNER_SCAN_CAP) { return true; }
    if (flags[k] != FLAG_MERGE) { return false; }
    let lk = info[k].y;
    let xk = pos[k].xyz;
    let h = level_radius(params.h0, lk);
    for (var i = me.begin; i < me.end; i++) {
        *tested += 1u;
        if (*tested > PARTNER_SCAN_CAP) { return true; }
        if (i == k || flags[i] != FLAG_MERGE || info[i].y != lk) { continue; }
        let xi = pos[i].xyz;
        let dk = min_image(xk - xi, grid);
        if (dot(dk, dk) < h * h) { return true; }
    }
    return false;
}
//!walk partner_walk

// Whether a merge-marked slot of the cell [begin, end) has a merge-marked partner (or the check
// ran out of trips: the cell is listed unchecked). Merges only take marks away (MERGED, DEAD) and
// move only the particles they merge, so a cell without such a pair now merges nothing in any
// colour pass: it is not listed, and its workgroup is not launched.
fn may_merge(begin: u32, end: u32, cc: vec3<i32>) -> bool {
    var tested = 0u;
    return partner_walk(&tested, Slots(begin, end), cc);
}

fn axis_class(x: u32, split: u32) -> u32 {
    if (x < split) { return x % 3u; }
    return 3u + (x - split);
}

@compute @workgroup_size(WG_PARTICLES)
fn merge_cells(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let cell = thread_index(gid, nwg, WG_PARTICLES);
    if (cell >= grid.num_cells) { return; }
    let begin = cell_start[cell_entry(cell, grid)];
    let end = cell_start[cell_entry(cell + 1u, grid)];
    var marked = 0u;
    for (var k = begin; k < end; k++) { marked += u32(flags[k] == FLAG_MERGE); }
    if (marked == 0u) { return; }
    let d = grid.dims;
    let cc = vec3<u32>(cell % d.x, (cell / d.x) % d.y, cell / (d.x * d.y));
    if (!may_merge(begin, end, vec3<i32>(cc))) { return; }
    // the particles in the 27 cells (an empty range outside a walled axis adds 0)
    var nb = 0u;
    for (var kc = 0u; kc < 27u; kc++) {
        let e = cell_entries(vec3<i32>(cc), kc, grid);
        nb += cell_start[e.y] - cell_start[e.x];
    }
    // loop iterations of one merge invocation: the slot walk, and per marked slot the 27 cells
    // and its share of two neighbourhood scans (+16: what the tree reductions took before they
    // became workgroup atomics, kept as margin so the limit a shot meets has not moved)
    let share = nb / WG_PARTICLES + 1u;
    let estimate = (end - begin) + marked * (2u * (27u + share) + 16u);
    atomicMax(&load[1], estimate);
    if (estimate > LOOP_BUDGET) { atomicMax(&load[0], 1u); }
    let m = colour_map;
    let colour = (axis_class(cc.z, m.split.z) * m.classes.y + axis_class(cc.y, m.split.y))
        * m.classes.x + axis_class(cc.x, m.split.x);
    let slot = atomicAdd(&colour_count[colour], 1u);
    cells[colour_list[colour].x + slot] = cell;
}

@compute @workgroup_size(1)
fn merge_dispatch() {
    var listed = 0u;
    for (var c = 0u; c < arrayLength(&colour_list); c++) {
        let n = atomicLoad(&colour_count[c]);
        listed += n;
        merge_args[c] = groups_for(n, 1u);
    }
    atomicMax(&load[2], listed);
}
