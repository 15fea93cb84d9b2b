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

// A candidate split: particle i and its children's positions a and b, and how close another
// particle may come to either (squared).
struct Fit {
    i: u32,
    a: vec3<f32>,
    b: vec3<f32>,
    r2: f32,
}

// Whether particle k other than i is too close to a child (stops the walk).
fn fit_blocked(me: Fit, k: u32) -> bool {
    if (k == me.i) { return false; }
    let q = pos[k].xyz;
    let da = min_image(me.a - q, grid);
    let db = min_image(me.b - q, grid);
    return dot(da, da) < me.r2 || dot(db, db) < me.r2;
}
//!walk fit_walk

fn split_fits(i: u32, x: vec3<f32>, id: u32, level: u32) -> bool {
    let hc = level_radius(params.h0, level + 1u);
    let off = (params.split_offset * hc) * split_dir(id);
    let a = wrap_pos(x + off, grid);
    let b = wrap_pos(x - off, grid);
    if (!inside_walls(a, grid) || !inside_walls(b, grid)) { return false; }
    let r = params.min_distance * hc;
    return !fit_walk(Fit(i, a, b, r * r), cell_coord(x, grid));
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
