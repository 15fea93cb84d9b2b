// One pass of a stable LSD radix sort of (key, value) pairs, 4 bits per pass, tiles of 256.
// radix_count: per-tile digit histogram, stored digit-major (hist[d * num_tiles + tile]) so an
// exclusive scan of it gives every (digit, tile) its first output slot.
// radix_scatter: rank within the tile by a prefix sum of packed one-hot digit counters (16 digits
// x 16 bits in 8 u32), so equal digits keep their input order: the sort is stable and the output
// is the same on every run. Mirror: src/sim/reference/sort.rs.

struct RadixParams {
    n: u32,
    shift: u32,
    num_tiles: u32,
    _p0: u32,
}

@group(0) @binding(0) var<uniform> rp: RadixParams;
@group(0) @binding(1) var<storage, read_write> keys_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> hist: array<u32>;

var<workgroup> counts: array<atomic<u32>, 16>;
var<workgroup> packed: array<vec4<u32>, 512>;

fn tile_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

@compute @workgroup_size(256)
fn radix_count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let tile = tile_index(wid, nwg);
    if (t < 16u) { atomicStore(&counts[t], 0u); }
    workgroupBarrier();
    let i = tile * 256u + t;
    if (i < rp.n) {
        let d = (keys_in[i] >> rp.shift) & 15u;
        atomicAdd(&counts[d], 1u);
    }
    workgroupBarrier();
    if (t < 16u && tile < rp.num_tiles) {
        hist[t * rp.num_tiles + tile] = atomicLoad(&counts[t]);
    }
}

@compute @workgroup_size(256)
fn radix_scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) t: u32) {
    let tile = tile_index(wid, nwg);
    let i = tile * 256u + t;
    let live = i < rp.n;
    var key = 0u;
    var d = 0u;
    var lo = vec4<u32>(0u);
    var hi = vec4<u32>(0u);
    if (live) {
        key = keys_in[i];
        d = (key >> rp.shift) & 15u;
        // digit d counts in 16-bit field (d % 2) of word d / 2
        let word = d / 2u;
        let one = 1u << (16u * (d % 2u));
        if (word < 4u) { lo[word] = one; } else { hi[word - 4u] = one; }
    }
    packed[2u * t] = lo;
    packed[2u * t + 1u] = hi;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        var a = vec4<u32>(0u);
        var b = vec4<u32>(0u);
        if (t >= off) {
            a = packed[2u * (t - off)];
            b = packed[2u * (t - off) + 1u];
        }
        workgroupBarrier();
        packed[2u * t] = packed[2u * t] + a;
        packed[2u * t + 1u] = packed[2u * t + 1u] + b;
        workgroupBarrier();
    }
    if (live) {
        let word = d / 2u;
        var w: u32;
        if (word < 4u) { w = packed[2u * t][word]; } else { w = packed[2u * t + 1u][word - 4u]; }
        let inclusive = (w >> (16u * (d % 2u))) & 0xffffu;
        let dst = hist[d * rp.num_tiles + tile] + inclusive - 1u;
        keys_out[dst] = key;
        vals_out[dst] = vals_in[i];
    }
}
