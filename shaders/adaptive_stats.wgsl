// Adaptive bookkeeping: totals after the scans (single thread). The particles per level are
// counted by adaptive_split.wgsl into the words totals_split zeroes.
// Integer counters only, so the read-back is exact and deterministic. totals_split also writes
// the particle set's next live state (count, next id, single-level flag, dispatch arguments)
// into the counters' C_LIVE block, which the host's encoder copies over `live` once the split is
// done: the count never leaves the GPU inside a frame.
//!include shared/common.wgsl
//!include shared/adaptive.wgsl

@group(0) @binding(0) var<uniform> params: AdaptiveParams;
@group(0) @binding(1) var<storage, read_write> counters: array<atomic<u32>>;
@group(0) @binding(2) var<storage, read> scan: array<u32>;
@group(0) @binding(3) var<storage, read> flags: array<u32>;
@group(0) @binding(4) var<storage, read> live: Live;

// Total of an exclusive scan over the first n flags for the given bit.
fn scan_total(n: u32, bit: u32) -> u32 {
    if (n == 0u) { return 0u; }
    return scan[n - 1u] + select(0u, 1u, (flags[n - 1u] & bit) != 0u);
}

@compute @workgroup_size(1)
fn totals_merge() {
    let dead = scan_total(live.count, FLAG_DEAD);
    atomicStore(&counters[C_MERGES], dead);
    atomicStore(&counters[C_NEWCOUNT], live.count - dead);
}

@compute @workgroup_size(1)
fn totals_split() {
    let newcount = atomicLoad(&counters[C_NEWCOUNT]);
    let wanted = scan_total(live.count, FLAG_SPLIT);
    let done = min(wanted, params.capacity - newcount);
    let final_count = newcount + done;
    atomicStore(&counters[C_SPLIT_WANTED], wanted);
    atomicStore(&counters[C_SPLITS], done);
    atomicStore(&counters[C_SKIPPED], wanted - done);
    atomicStore(&counters[C_FINAL], final_count);
    atomicStore(&counters[C_NEXT_ID], live.next_id + done);
    for (var l = 0u; l <= MAX_LEVEL; l++) {
        atomicStore(&counters[C_LEVELS + l], 0u);
    }
    // the live state after this run (shared/live.wgsl `Live`, word for word)
    atomicStore(&counters[C_LIVE], final_count);
    atomicStore(&counters[C_LIVE + 1u], live.next_id + done);
    atomicStore(&counters[C_LIVE + 2u], select(0u, live.single_level, done == 0u));
    atomicStore(&counters[C_LIVE + 3u], live.count);
    let gp = groups_for(final_count, WG_PARTICLES);
    let gb = groups_for(final_count, WG_BLOCK);
    for (var k = 0u; k < 4u; k++) {
        atomicStore(&counters[C_LIVE + 4u + k], gp[k]);
        atomicStore(&counters[C_LIVE + 8u + k], gb[k]);
    }
    // the frame's totals (the host zeroes them when a frame starts)
    atomicAdd(&counters[C_FRAME_MERGES], atomicLoad(&counters[C_MERGES]));
    atomicAdd(&counters[C_FRAME_SPLITS], done);
    atomicAdd(&counters[C_FRAME_SKIPPED], wanted - done);
}
