// Exclusive prefix sum of u32, reduce-then-scan in blocks of SCAN_BLOCK = WG_SCAN x SCAN_ITEMS
// values: `scan_reduce` writes each block's total (the next level's input), the next level
// scans those totals, and `scan_blocks` scans each block from its scanned total (the last level
// from 0). The one scan of the project: the grid's per-entry counts (the cell table) and the
// adaptive stage's flag ranks. Integer adds, so the result does not depend on execution order.
// Mirror: src/sim/reference/scan.rs.
//
// Each thread takes SCAN_ITEMS consecutive values straight from the input, four at a time
// (vec4 loads), and the threads' totals are scanned Hillis-Steele in workgroup memory. On CPU
// devices a memory access of non-consecutive lanes costs a load per lane, so the loads and
// stores per value are what a scan costs there: here 1/4 + 1/4 loads and 1 store per value,
// where staging the block in workgroup memory took 8 accesses per value (plus 2 to add the
// block sums back).
//!include shared/live.wgsl

struct ScanParams {
    // values at this level
    n: u32,
    // 0: scan the values; otherwise scan (value & mask) != 0 as 0/1
    mask: u32,
    // 1: values at or past live.count count as 0 and are not written (a per-particle scan's
    // first level)
    live_only: u32,
    // 1: scan_blocks starts block g from offsets[g] (every level but the last)
    offsets_on: u32,
}

// The input is read as quads, so its binding covers whole quads (PrefixScan checks that the
// caller's span does, and pads the sums it owns).
@group(0) @binding(0) var<storage, read> live: Live;
@group(0) @binding(1) var<storage, read> input: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> output: array<u32>;
@group(0) @binding(3) var<storage, read_write> sums: array<u32>;
@group(0) @binding(4) var<storage, read> offsets: array<u32>;
@group(1) @binding(0) var<uniform> sp: ScanParams;

const SCAN_BLOCK: u32 = WG_SCAN * SCAN_ITEMS;
const QUADS: u32 = SCAN_ITEMS / 4u;
var<workgroup> totals: array<u32, WG_SCAN>;

// Values this level scans (the rest count 0).
fn level_len() -> u32 {
    if (sp.live_only != 0u) { return min(sp.n, live.count); }
    return sp.n;
}

// Values 4q .. 4q+3 as the scan counts them.
fn quad(q: u32, n: u32) -> vec4<u32> {
    if (4u * q >= n) { return vec4<u32>(0u); }
    var v = input[q];
    if (sp.mask != 0u) {
        v = select(vec4<u32>(0u), vec4<u32>(1u), (v & vec4<u32>(sp.mask)) != vec4<u32>(0u));
    }
    let index = vec4<u32>(4u * q) + vec4<u32>(0u, 1u, 2u, 3u);
    return select(vec4<u32>(0u), v, index < vec4<u32>(n));
}

// The total of the thread's SCAN_ITEMS values from quad `first`.
fn run_total(first: u32, n: u32) -> u32 {
    var sum = 0u;
    for (var k = 0u; k < QUADS; k++) {
        let v = quad(first + k, n);
        sum += (v.x + v.y) + (v.z + v.w);
    }
    return sum;
}

// totals[t] becomes the inclusive scan of the threads' totals.
fn scan_totals(t: u32, run: u32) {
    totals[t] = run;
    workgroupBarrier();
    for (var off = 1u; off < WG_SCAN; off = off * 2u) {
        var a = 0u;
        if (t >= off) { a = totals[t - off]; }
        workgroupBarrier();
        totals[t] = totals[t] + a;
        workgroupBarrier();
    }
}

// sums[g] = the total of block g.
@compute @workgroup_size(WG_SCAN)
fn scan_reduce(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    let run = run_total((g * SCAN_BLOCK + t * SCAN_ITEMS) / 4u, level_len());
    scan_totals(t, run);
    if (t == WG_SCAN - 1u) { sums[g] = totals[t]; }
}

// output[i] = (offsets[block of i]) + the values before i in its block.
@compute @workgroup_size(WG_SCAN)
fn scan_blocks(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let g = wid.y * nwg.x + wid.x;
    let n = level_len();
    let first = (g * SCAN_BLOCK + t * SCAN_ITEMS) / 4u;
    let run = run_total(first, n);
    scan_totals(t, run);
    var acc = totals[t] - run;
    if (sp.offsets_on != 0u) { acc += offsets[g]; }
    for (var k = 0u; k < QUADS; k++) {
        let i = 4u * (first + k);
        if (i >= n) { break; }
        let v = quad(first + k, n);
        output[i] = acc;
        acc += v.x;
        if (i + 1u < n) { output[i + 1u] = acc; }
        acc += v.y;
        if (i + 2u < n) { output[i + 2u] = acc; }
        acc += v.z;
        if (i + 3u < n) { output[i + 3u] = acc; }
        acc += v.w;
    }
}
