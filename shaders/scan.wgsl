// Exclusive prefix sum of u32 in blocks of WG_SCAN x SCAN_ITEMS (in workgroup memory); the
// block sums are scanned by the next level and added back (`scan_add`). The one scan of the
// project: the grid's per-entry counts (the cell table) and the adaptive stage's flag ranks.
// Integer adds, so the result does not depend on execution order. Mirror: src/sim/reference/scan.rs.
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

// One block: WG_SCAN threads x SCAN_ITEMS values. Each thread scans SCAN_ITEMS consecutive
// values serially and the threads' totals are scanned Hillis-Steele: far fewer barriers per value
// than a thread per value (a barrier is costly on CPU devices, where a workgroup's invocations
// take turns; there WG_SCAN is one SIMD batch). Loads and stores are coalesced through
// workgroup memory.
const SCAN_BLOCK: u32 = WG_SCAN * SCAN_ITEMS;
var<workgroup> s: array<u32, SCAN_BLOCK>;
var<workgroup> totals: array<u32, WG_SCAN>;

// output[i] = sum of the values before i in its block; sums[block] = the block's total.
@compute @workgroup_size(WG_SCAN)
fn scan_blocks(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    let base = g * SCAN_BLOCK;
    var n = sp.n;
    if (sp.live_only != 0u) { n = min(n, live.count); }
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        let j = k * WG_SCAN + t;
        var v = 0u;
        if (base + j < n) {
            v = input[base + j];
            if (sp.mask != 0u) { v = select(0u, 1u, (v & sp.mask) != 0u); }
        }
        s[j] = v;
    }
    workgroupBarrier();
    // this thread's run, exclusive in place
    var run = 0u;
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        let v = s[t * SCAN_ITEMS + k];
        s[t * SCAN_ITEMS + k] = run;
        run += v;
    }
    totals[t] = run;
    workgroupBarrier();
    for (var off = 1u; off < WG_SCAN; off = off * 2u) {
        var a = 0u;
        if (t >= off) { a = totals[t - off]; }
        workgroupBarrier();
        totals[t] = totals[t] + a;
        workgroupBarrier();
    }
    let before = totals[t] - run;
    for (var k = 0u; k < SCAN_ITEMS; k++) { s[t * SCAN_ITEMS + k] += before; }
    workgroupBarrier();
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        let j = k * WG_SCAN + t;
        if (base + j < sp.n) { output[base + j] = s[j]; }
    }
    if (t == WG_SCAN - 1u) { sums[g] = totals[WG_SCAN - 1u]; }
}

// output[i] += input[block of i], where input holds the next level's scanned block sums; a
// workgroup per block, as scan_blocks.
@compute @workgroup_size(WG_SCAN)
fn scan_add(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    let add = input[g];
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        let i = g * SCAN_BLOCK + k * WG_SCAN + t;
        if (i < sp.n) { output[i] = output[i] + add; }
    }
}
