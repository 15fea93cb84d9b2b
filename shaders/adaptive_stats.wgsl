// Adaptive bookkeeping: totals after the scans (single thread) and particles per level.
// Integer counters only, so the read-back is exact and deterministic.
//!include shared/adaptive.wgsl

@group(0) @binding(0) var<uniform> params: AdaptiveParams;
@group(0) @binding(1) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(2) var<storage, read> scan: array<u32>;
@group(0) @binding(3) var<storage, read> flags: array<u32>;
@group(0) @binding(4) var<storage, read> info: array<vec2<u32>>;

// Total of an exclusive scan over the first n flags for the given bit.
fn scan_total(n: u32, bit: u32) -> u32 {
    if (n == 0u) { return 0u; }
    return scan[n - 1u] + select(0u, 1u, (flags[n - 1u] & bit) != 0u);
}

@compute @workgroup_size(1)
fn totals_merge() {
    let dead = scan_total(params.count, FLAG_DEAD);
    atomicStore(&counters[C_MERGES], dead);
    atomicStore(&counters[C_NEWCOUNT], params.count - dead);
}

@compute @workgroup_size(1)
fn totals_split() {
    let newcount = atomicLoad(&counters[C_NEWCOUNT]);
    let wanted = scan_total(params.count, FLAG_SPLIT);
    let done = min(wanted, params.capacity - newcount);
    atomicStore(&counters[C_SPLIT_WANTED], wanted);
    atomicStore(&counters[C_SPLITS], done);
    atomicStore(&counters[C_SKIPPED], wanted - done);
    atomicStore(&counters[C_FINAL], newcount + done);
    atomicStore(&counters[C_NEXT_ID], params.next_id + done);
    for (var l = 0u; l < MAX_LEVELS; l++) {
        atomicStore(&counters[C_LEVELS + l], 0u);
    }
}

@compute @workgroup_size(256)
fn count_levels(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_index(gid, nwg, 256u);
    if (i >= atomicLoad(&counters[C_FINAL])) { return; }
    atomicAdd(&counters[C_LEVELS + min(info[i].y, MAX_LEVELS - 1u)], 1u);
}
