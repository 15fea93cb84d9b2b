// Shared by the adaptive split/merge stages (shaders/adaptive_*.wgsl); mirrored in f64 by
// src/sim/reference/common.rs (same names).
//!include shared/common.wgsl

// Mirror of sim::adaptive::AdaptiveParams (byte layout must match). `count` and `next_id` are
// the f64 mirror's inputs; the GPU reads them from `live` (shared/live.wgsl).
struct AdaptiveParams {
    count: u32,
    capacity: u32,
    max_level: u32,
    next_id: u32,
    h0: f32,
    kp: f32,
    kc: f32,
    split_threshold: f32,
    merge_threshold: f32,
    min_distance: f32,
    split_offset: f32,
    pad0: u32,
}

// Per-particle flags of one adaptive run.
const FLAG_MERGE: u32 = 1u;   // marked for merging
const FLAG_SPLIT: u32 = 2u;   // marked for splitting and both children fit
const FLAG_MERGED: u32 = 4u;  // product of a merge in this run (takes part in no other)
const FLAG_DEAD: u32 = 8u;    // merged into a neighbour; compacted away

// Layout of the counters buffer (read back after each run).
const C_MERGES: u32 = 0u;
const C_NEWCOUNT: u32 = 1u;
const C_SPLIT_WANTED: u32 = 2u;
const C_SPLITS: u32 = 3u;
const C_SKIPPED: u32 = 4u;
const C_FINAL: u32 = 5u;
const C_NEXT_ID: u32 = 6u;
// the particles per level, MAX_LEVEL + 1 words (the prelude's MAX_LEVEL, `ground::levels`)
const C_LEVELS: u32 = 8u;
// the next `Live` (12 words), copied over `live` after the split
const C_LIVE: u32 = 32u;
const_assert C_LEVELS + MAX_LEVEL < C_LIVE;
// merges, splits and skipped splits summed over the frame's substeps
const C_FRAME_MERGES: u32 = 44u;
const C_FRAME_SPLITS: u32 = 45u;
const C_FRAME_SKIPPED: u32 = 46u;
const N_COUNTERS: u32 = 48u;


// Kernel radius of level l: h0 * 2^(-l/3).
fn level_radius(h0: f32, level: u32) -> f32 {
    return h0 * exp2(-f32(level) / 3.0);
}

// Deterministic pseudo-random unit direction of a split, from the particle id only (so a
// particle splits the same way on every run and machine); uniform on the sphere.
fn split_dir(id: u32) -> vec3<f32> {
    let a = pcg_hash(id);
    let b = pcg_hash(a);
    // 24-bit fractions are exact in f32 (and in the f64 mirror).
    let u = f32(a >> 8u) / 16777216.0;
    let v = f32(b >> 8u) / 16777216.0;
    let z = 1.0 - 2.0 * u;
    let s = sqrt(max(0.0, 1.0 - z * z));
    let phi = 6.283185307179586 * v;
    return vec3<f32>(s * cos(phi), s * sin(phi), z);
}

// Wraps a position into the domain along periodic axes.
fn wrap_pos(p: vec3<f32>, g: GridParams) -> vec3<f32> {
    var r = p;
    if ((g.periodic & 1u) != 0u) {
        r.x = r.x - g.domain_size.x * floor((r.x - g.domain_min.x) / g.domain_size.x);
    }
    if ((g.periodic & 4u) != 0u) {
        r.z = r.z - g.domain_size.z * floor((r.z - g.domain_min.z) / g.domain_size.z);
    }
    return r;
}

// Inside the box along the walled axes (periodic axes are always inside after wrap_pos).
fn inside_walls(p: vec3<f32>, g: GridParams) -> bool {
    let lo = g.domain_min;
    let hi = g.domain_min + g.domain_size;
    var ok = p.y >= lo.y && p.y <= hi.y;
    if ((g.periodic & 1u) == 0u) { ok = ok && p.x >= lo.x && p.x <= hi.x; }
    if ((g.periodic & 4u) == 0u) { ok = ok && p.z >= lo.z && p.z <= hi.z; }
    return ok;
}
