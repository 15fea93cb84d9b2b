// Exclusive prefix sum of u32 in blocks of 256 (Hillis-Steele in workgroup memory), plus the
// add-back of scanned block sums. Integer adds: the result does not depend on execution order.
// Mirror: src/sim/reference/sort.rs (`scan_blocks`, `scan_add`).

struct ScanParams {
    n: u32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
}

@group(0) @binding(0) var<uniform> sp: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

var<workgroup> s: array<u32, 256>;

fn group_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

@compute @workgroup_size(256)
fn scan_blocks(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let g = group_index(wid, nwg);
    let i = g * 256u + t;
    var v = 0u;
    if (i < sp.n) { v = data[i]; }
    s[t] = v;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        var a = 0u;
        if (t >= off) { a = s[t - off]; }
        workgroupBarrier();
        s[t] = s[t] + a;
        workgroupBarrier();
    }
    if (i < sp.n) { data[i] = s[t] - v; }
    if (t == 255u) { sums[g] = s[255]; }
}

@compute @workgroup_size(256)
fn scan_add(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) t: u32) {
    let g = group_index(wid, nwg);
    let i = g * 256u + t;
    if (i < sp.n) { data[i] = data[i] + sums[g]; }
}
