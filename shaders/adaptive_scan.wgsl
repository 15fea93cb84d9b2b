// Exclusive prefix sum of u32 (optionally of a flag bit) for the adaptive stage: per-block
// scans of 256, the block sums scanned recursively, then added back. Integer sums, so the result
// is exact and independent of scheduling. (A generic scan also lives in the radix sort; to be
// deduplicated.)
struct ScanParams {
    n: u32,
    // 0: scan the values; otherwise scan (value & mask) != 0 as 0/1.
    mask: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> sp: ScanParams;
@group(0) @binding(1) var<storage, read> input: array<u32>;
@group(0) @binding(2) var<storage, read_write> output: array<u32>;
@group(0) @binding(3) var<storage, read_write> sums: array<u32>;

var<workgroup> tmp: array<u32, 256>;

@compute @workgroup_size(256)
fn scan_blocks(@builtin(local_invocation_index) li: u32,
               @builtin(workgroup_id) wid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * 256u + li;
    var v = 0u;
    if (i < sp.n) {
        v = input[i];
        if (sp.mask != 0u) { v = select(0u, 1u, (v & sp.mask) != 0u); }
    }
    tmp[li] = v;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        var add = 0u;
        if (li >= off) { add = tmp[li - off]; }
        workgroupBarrier();
        tmp[li] = tmp[li] + add;
        workgroupBarrier();
    }
    if (i < sp.n) { output[i] = tmp[li] - v; }
    if (li == 255u) { sums[block] = tmp[255]; }
}

// output[i] += input[block of i], where input holds the scanned block sums.
@compute @workgroup_size(256)
fn add_block_offsets(@builtin(local_invocation_index) li: u32,
                     @builtin(workgroup_id) wid: vec3<u32>,
                     @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * 256u + li;
    if (i < sp.n) { output[i] = output[i] + input[block]; }
}
