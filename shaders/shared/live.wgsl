// The particle set's GPU-resident scalars (src/gpu/live.rs `Live`, same byte layout): the live
// count that bounds every particle kernel, and the indirect dispatch arguments over it. The
// adaptive stage rewrites them on the GPU when split and merge change the count; the host writes
// them only between frames.
struct Live {
    count: u32,
    next_id: u32,
    // 1 while every particle is on level 0 (PBF's fast path)
    single_level: u32,
    // particles of the last density solve (before split and merge)
    solved_count: u32,
    // (x, y, z, unused) workgroups over `count` for WG_PARTICLES and WG_BLOCK threads
    groups_particles: vec4<u32>,
    groups_block: vec4<u32>,
}

// Workgroups for `threads` threads in groups of `wg`: up to MAX_GROUPS_X along x, then rows
// along y. Mirror: gpu::stage::groups_for.
fn groups_for(threads: u32, wg: u32) -> vec4<u32> {
    let groups = threads / wg + select(0u, 1u, threads % wg != 0u);
    if (groups == 0u) { return vec4<u32>(0u, 1u, 1u, 0u); }
    let x = min(groups, MAX_GROUPS_X);
    return vec4<u32>(x, groups / x + select(0u, 1u, groups % x != 0u), 1u, 0u);
}
