// Adaptive stage 4: split (paper section 5.2.1). A marked particle becomes two children of
// level l+1 at x +- split_offset * h_child * dir(id); the first reuses its slot and id, the
// second goes to newcount + (its rank in the scan of split marks) with id next_id + rank.
// Ranks beyond the free capacity are skipped (counted by totals_split). Each thread also counts
// the final level of its slot (and of its child's) into the per-level counters that
// totals_split zeroed: no pass of its own for the count.
//!include shared/common.wgsl
//!include shared/adaptive.wgsl

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> params: AdaptiveParams;
@group(0) @binding(2) var<storage, read_write> counters: array<atomic<u32>>;
// Exclusive scan of the split marks.
@group(0) @binding(3) var<storage, read> scan: array<u32>;
@group(0) @binding(4) var<storage, read> flags: array<u32>;
@group(0) @binding(5) var<storage, read_write> pos: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> info: array<vec2<u32>>;
@group(0) @binding(9) var<storage, read> live: Live;

@compute @workgroup_size(WG_BLOCK)
fn adaptive_split(@builtin(global_invocation_id) gid: vec3<u32>,
                  @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg, WG_BLOCK);
    let newcount = atomicLoad(&counters[C_NEWCOUNT]);
    if (i >= live.count || i >= newcount) { return; }
    let inf = info[i];
    let k = scan[i];
    if ((flags[i] & FLAG_SPLIT) == 0u || k >= atomicLoad(&counters[C_SPLITS])) {
        atomicAdd(&counters[C_LEVELS + min(inf.y, MAX_LEVEL)], 1u);
        return;
    }
    atomicAdd(&counters[C_LEVELS + min(inf.y + 1u, MAX_LEVEL)], 2u);
    let slot = newcount + k;
    let p = pos[i];
    let hc = level_radius(params.h0, inf.y + 1u);
    let off = (params.split_offset * hc) * split_dir(inf.x);
    pos[i] = vec4<f32>(wrap_pos(p.xyz + off, grid), p.w);
    pos[slot] = vec4<f32>(wrap_pos(p.xyz - off, grid), p.w);
    vel[slot] = vel[i];
    thermo[slot] = thermo[i];
    info[i] = vec2<u32>(inf.x, inf.y + 1u);
    info[slot] = vec2<u32>(live.next_id + k, inf.y + 1u);
}
