// Exclusive prefix sum of u32 in blocks of WG_BLOCK (Hillis-Steele in workgroup memory); the
// block sums are scanned by the next level and added back (`scan_add`). The one scan of the
// project: the grid's per-entry counts (the cell table) and the adaptive stage's flag ranks. Integer adds,
// so the result does not depend on execution order. Mirror: src/sim/reference/scan.rs.
//!include shared/live.wgsl

struct ScanParams {
    // values at this level
    n: u32,
    // 0: scan the values; otherwise scan (value & mask) != 0 as 0/1
    mask: u32,
    // 1: values at or past live.count count as 0 (a per-particle scan's first level)
    live_only: u32,
    _pad: u32,
}

@group(0) @binding(0) var<storage, read> live: Live;
@group(0) @binding(1) var<storage, read> input: array<u32>;
@group(0) @binding(2) var<storage, read_write> output: array<u32>;
@group(0) @binding(3) var<storage, read_write> sums: array<u32>;
@group(1) @binding(0) var<uniform> sp: ScanParams;

var<workgroup> s: array<u32, WG_BLOCK>;

// output[i] = sum of the values before i in its block; sums[block] = the block's total.
@compute @workgroup_size(WG_BLOCK)
fn scan_blocks(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    let i = g * WG_BLOCK + t;
    var n = sp.n;
    if (sp.live_only != 0u) { n = min(n, live.count); }
    var v = 0u;
    if (i < n) {
        v = input[i];
        if (sp.mask != 0u) { v = select(0u, 1u, (v & sp.mask) != 0u); }
    }
    s[t] = v;
    workgroupBarrier();
    for (var off = 1u; off < WG_BLOCK; off = off * 2u) {
        var a = 0u;
        if (t >= off) { a = s[t - off]; }
        workgroupBarrier();
        s[t] = s[t] + a;
        workgroupBarrier();
    }
    if (i < sp.n) { output[i] = s[t] - v; }
    if (t == WG_BLOCK - 1u) { sums[g] = s[WG_BLOCK - 1u]; }
}

// output[i] += input[block of i], where input holds the next level's scanned block sums.
@compute @workgroup_size(WG_BLOCK)
fn scan_add(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    let i = g * WG_BLOCK + t;
    if (i < sp.n) { output[i] = output[i] + input[g]; }
}
