// Adaptive stage 1: shape energy (paper eq. 20) and split/merge marks.
// A split is marked only where both children fit: no other particle closer than
// min_distance * h_child to either child (read-only on positions, so one pass, race-free).
//!include shared/common.wgsl
//!include shared/adaptive.wgsl

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> params: AdaptiveParams;
@group(0) @binding(2) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> info: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> cell_start: array<u32>;
@group(0) @binding(6) var<storage, read_write> flags: array<u32>;
@group(0) @binding(7) var<storage, read> live: Live;

fn split_fits(i: u32, x: vec3<f32>, id: u32, level: u32) -> bool {
    let hc = level_radius(params.h0, level + 1u);
    let off = (params.split_offset * hc) * split_dir(id);
    let a = wrap_pos(x + off, grid);
    let b = wrap_pos(x - off, grid);
    if (!inside_walls(a, grid) || !inside_walls(b, grid)) { return false; }
    let r = params.min_distance * hc;
    let r2 = r * r;
    let c = cell_coord(x, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                for (var k = cell_start[cell_entry(u32(n), grid)]; k < cell_start[cell_entry(u32(n) + 1u, grid)]; k++) {
                    if (k == i) { continue; }
                    let q = pos[k].xyz;
                    let da = min_image(a - q, grid);
                    let db = min_image(b - q, grid);
                    if (dot(da, da) < r2 || dot(db, db) < r2) { return false; }
                }
            }
        }
    }
    return true;
}

@compute @workgroup_size(WG_BLOCK)
fn adaptive_mark(@builtin(global_invocation_id) gid: vec3<u32>,
                 @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg, WG_BLOCK);
    if (i >= live.count) { return; }
    var t = thermo[i];
    let e = params.kp * (1.0 - exp(-params.kc * t.z));
    t.w = e;
    thermo[i] = t;
    let inf = info[i];
    var flag = 0u;
    if (e < params.merge_threshold && inf.y > 0u) {
        flag = FLAG_MERGE;
    } else if (e > params.split_threshold && inf.y < params.max_level
               && split_fits(i, pos[i].xyz, inf.x, inf.y)) {
        flag = FLAG_SPLIT;
    }
    flags[i] = flag;
}
