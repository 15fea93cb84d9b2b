// Neighbour grid build: a counting sort of the particles by (cell, x slice) key of the predicted
// positions. cell_keys writes each key and counts it (counts[key + 1], atomics: the counts do not
// depend on the order of the adds); the exclusive scan of the counts (gpu::scan) writes
// cell_start, whose entry key + 1 is then the first slot of key; cell_scatter takes a slot per
// particle with an atomic add there, which leaves cell_start[e] = the first slot of entry e;
// cell_order puts each entry's particles in index order (the scatter's order within an entry
// depends on the thread schedule; index order is that of a stable sort). The result is the same
// on every run. Mirror: src/sim/reference/grid.rs.
//!include shared/common.wgsl

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<storage, read> pos_in: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> keys: array<u32>;
@group(0) @binding(3) var<storage, read_write> order: array<u32>;
@group(0) @binding(4) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> cell_start: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read> live: Live;
// the scatter's slots (in thread-schedule order within an entry)
@group(0) @binding(7) var<storage, read_write> scattered: array<u32>;

// counts = 0 (one thread per table entry)
@compute @workgroup_size(WG_PARTICLES)
fn cell_clear(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let e = linear_id(gid, nwg);
    if (e > grid.num_cells * grid.x_slices) { return; }
    atomicStore(&counts[e], 0u);
}

@compute @workgroup_size(WG_PARTICLES)
fn cell_keys(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let k = slice_key(pos_in[i].xyz, grid);
    keys[i] = k;
    atomicAdd(&counts[k + 1u], 1u);
}

@compute @workgroup_size(WG_PARTICLES)
fn cell_scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    scattered[atomicAdd(&cell_start[keys[i] + 1u], 1u)] = i;
}

// Each particle's final slot: its entry's first slot plus the number of the entry's particles
// with a lower index (O(entry size) per particle: a few; llvmpipe's 65535-iteration budget per
// invocation holds up to 65535 particles in one slice).
@compute @workgroup_size(WG_PARTICLES)
fn cell_order(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= live.count) { return; }
    let v = scattered[s];
    let k = keys[v];
    let a = atomicLoad(&cell_start[k]);
    let b = atomicLoad(&cell_start[k + 1u]);
    var r = 0u;
    for (var t = a; t < b; t++) { r += u32(scattered[t] < v); }
    order[a + r] = v;
}
