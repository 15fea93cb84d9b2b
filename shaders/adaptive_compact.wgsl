// Adaptive stage 3: remove merged-away particles in place. With newcount live particles, the
// dead slots below newcount ("holes", ranked by the scan of dead flags) are filled by the live
// particles at or above newcount (ranked likewise), so sources and destinations never overlap
// and no scratch copy of the particle arrays is needed. Deterministic; the next grid build
// re-sorts by cell anyway.
//!include shared/adaptive.wgsl

@group(0) @binding(0) var<uniform> params: AdaptiveParams;
@group(0) @binding(1) var<storage, read> counters: array<u32>;
// Exclusive scan of the dead flags.
@group(0) @binding(2) var<storage, read> scan: array<u32>;
@group(0) @binding(3) var<storage, read_write> flags: array<u32>;
@group(0) @binding(4) var<storage, read_write> hole_index: array<u32>;
@group(0) @binding(5) var<storage, read_write> pos: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> info: array<vec2<u32>>;
@group(0) @binding(9) var<storage, read> live: Live;

@compute @workgroup_size(WG_BLOCK)
fn compact_holes(@builtin(global_invocation_id) gid: vec3<u32>,
                 @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg, WG_BLOCK);
    if (i >= live.count) { return; }
    if (i < counters[C_NEWCOUNT] && (flags[i] & FLAG_DEAD) != 0u) {
        hole_index[scan[i]] = i;
    }
}

@compute @workgroup_size(WG_BLOCK)
fn compact_move(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = thread_index(gid, nwg, WG_BLOCK);
    let newcount = counters[C_NEWCOUNT];
    if (j >= live.count || j < newcount) { return; }
    let f = flags[j];
    if ((f & FLAG_DEAD) == 0u) {
        let rank = (j - newcount) - (scan[j] - scan[newcount]);
        let dst = hole_index[rank];
        pos[dst] = pos[j];
        vel[dst] = vel[j];
        thermo[dst] = thermo[j];
        info[dst] = info[j];
        flags[dst] = f;
    }
    // Slots past the live range carry no marks into the split scan.
    flags[j] = 0u;
}
