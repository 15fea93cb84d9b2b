// Neighbour grid build: (cell, x slice) keys of the predicted positions, then (after the radix sort) the
// cell table from the sorted keys. Each thread writes the starts of the cells between its key and
// its predecessor's: no atomics, deterministic. Mirror: src/sim/reference/grid.rs.
//!include shared/common.wgsl

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<storage, read_write> pos_in: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> keys: array<u32>;
@group(0) @binding(3) var<storage, read_write> vals: array<u32>;
@group(0) @binding(4) var<storage, read_write> cell_start: array<u32>;
@group(0) @binding(5) var<storage, read> live: Live;

@compute @workgroup_size(WG_PARTICLES)
fn cell_keys(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    keys[i] = slice_key(pos_in[i].xyz, grid);
    vals[i] = i;
}

@compute @workgroup_size(WG_PARTICLES)
fn cell_table(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    let n = live.count;
    if (i >= n) { return; }
    let k = keys[i];
    var first = 0u;
    if (i > 0u) { first = keys[i - 1u] + 1u; }
    for (var c = first; c <= k; c = c + 1u) { cell_start[c] = i; }
    if (i == n - 1u) {
        for (var c = k + 1u; c <= grid.num_cells * grid.x_slices; c = c + 1u) { cell_start[c] = n; }
    }
}
