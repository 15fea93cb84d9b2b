// One pass of a stable LSD radix sort of (key, value) pairs, 4 bits per pass, tiles of
// WG_BLOCK. The first live.count pairs are sorted; the histogram has a column for every tile of
// the capacity (`num_tiles`), and radix_count runs over all of them so that the tiles past the
// live count hold zeros.
// radix_count: per-tile digit histogram, stored digit-major (hist[d * num_tiles + tile]) so an
// exclusive scan of it (`offsets`, gpu::scan) gives every (digit, tile) its first output slot.
// radix_scatter: rank within the tile by a prefix sum of packed one-hot digit counters (16 digits
// x 16 bits in 8 u32), so equal digits keep their input order: the sort is stable and the output
// is the same on every run. Mirror: src/sim/reference/radix_sort.rs.
//!include shared/live.wgsl

struct RadixParams {
    shift: u32,
    num_tiles: u32,
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<storage, read> live: Live;
@group(0) @binding(1) var<storage, read_write> keys_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> hist: array<u32>;
@group(0) @binding(6) var<storage, read> offsets: array<u32>;
@group(1) @binding(0) var<uniform> rp: RadixParams;

var<workgroup> counts: array<atomic<u32>, 16>;
var<workgroup> packed: array<vec4<u32>, 2u * WG_BLOCK>;

fn tile_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

@compute @workgroup_size(WG_BLOCK)
fn radix_count(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) t: u32) {
    let tile = tile_index(wid, nwg);
    if (t < 16u) { atomicStore(&counts[t], 0u); }
    workgroupBarrier();
    let i = tile * WG_BLOCK + t;
    if (i < live.count) {
        let d = (keys_in[i] >> rp.shift) & 15u;
        atomicAdd(&counts[d], 1u);
    }
    workgroupBarrier();
    if (t < 16u && tile < rp.num_tiles) {
        hist[t * rp.num_tiles + tile] = atomicLoad(&counts[t]);
    }
}

@compute @workgroup_size(WG_BLOCK)
fn radix_scatter(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) t: u32) {
    let tile = tile_index(wid, nwg);
    let i = tile * WG_BLOCK + t;
    let alive = i < live.count;
    var key = 0u;
    var d = 0u;
    var lo = vec4<u32>(0u);
    var hi = vec4<u32>(0u);
    if (alive) {
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
    for (var off = 1u; off < WG_BLOCK; off = off * 2u) {
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
    if (alive) {
        let word = d / 2u;
        var w: u32;
        if (word < 4u) { w = packed[2u * t][word]; } else { w = packed[2u * t + 1u][word - 4u]; }
        let inclusive = (w >> (16u * (d % 2u))) & 0xffffu;
        let dst = offsets[d * rp.num_tiles + tile] + inclusive - 1u;
        keys_out[dst] = key;
        vals_out[dst] = vals_in[i];
    }
}
