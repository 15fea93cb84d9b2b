// The neighbour walks, one template for every pair function (src/gpu/shaders.rs `WALKS` names
// each use; a stage's line `//!walk NAME` becomes the function NAME). Words: WALK_NAME the
// function, WALK_PARAMS its leading parameters (an accumulator and the particle `me`, as the
// pair function takes them); PAIR[[j]] and WALL[[k]] the calls for a fluid candidate j and a
// wall particle k, SKIP_WALLS[[y]] whether the walls' row at cell row y is out of the particle's
// reach. A use without walls leaves the //!walls block out. Every walk visits the 27 cells around
// a cell in one order, z slowest and x fastest (the f64 mirrors' order), and within a cell its
// slots in table order: the sums over neighbours depend on it.
//!template scan
// The search around the particle's position (no mask): the candidates of the 9 rows of slices
// around its cell, then the walls' rows.
fn WALK_NAME(WALK_PARAMS) {
    let c = cell_coord(me.p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = row_entries(me.p, c, dy, dz, grid);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j_end = cell_start[e.y];
                for (var j = cell_start[e.x]; j < j_end; j++) { PAIR[[j]]; }
//!walls
                if (SKIP_WALLS[[c.y + dy]]) { continue; }
                let we = e - vec2<u32>(wall_shift(c.y + dy, c.z + dz, grid));
                let k_end = bcell_start[we.y];
                for (var k = bcell_start[we.x]; k < k_end; k++) { WALL[[k]]; }
//!end walls
            }
        }
    }
}
//!template build
// The first compute_lambda's walk (pbf.wgsl "neighbour mask"): the rows around the anchor, all
// of each row's candidates, then the walls; PAIR says whether a candidate is a neighbour, and the
// mask it returns records those (`masked` reads it: the same rows, the same offsets).
fn WALK_NAME(WALK_PARAMS, an: Anchor) -> Mask {
    var m = Mask(vec4<u32>(0u), 0u, 0u);
    var off = 0u;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = anchor_row(an, dy, dz);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j0 = cell_start[e.x];
                let j1 = cell_start[e.y];
                var bits = vec2<u32>(0u);
                for (var j = j0; j < j1; j++) {
                    if (PAIR[[j]]) {
                        let k = j - j0;
                        bits.x |= select(0u, 1u << (k & 31u), k < 32u);
                        bits.y |= select(0u, 1u << (k & 31u), k >= 32u && k < 64u);
                    }
                }
                mask_put(&m, off, bits, seg_bits(off, j1 - j0, me.k.single));
                off += j1 - j0;
//!walls
                if (SKIP_WALLS[[an.c.y + dy]]) { continue; }
                let we = e - vec2<u32>(wall_shift(an.c.y + dy, an.c.z + dz, grid));
                let k_end = bcell_start[we.y];
                for (var k = bcell_start[we.x]; k < k_end; k++) { WALL[[k]]; }
//!end walls
            }
        }
    }
    return m;
}
//!template masked
// The neighbours the first compute_lambda recorded (pbf.wgsl "neighbour mask"): the same rows
// around the anchor, each row's set bits, then its candidates past the mask, then the walls.
fn WALK_NAME(WALK_PARAMS, an: Anchor, m: Mask) {
    var off = 0u;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = anchor_row(an, dy, dz);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j0 = cell_start[e.x];
                let j1 = cell_start[e.y];
                let nb = seg_bits(off, j1 - j0, me.k.single);
                var bits = mask_get(m, off, nb);
                off += j1 - j0;
                // one loop over both words, two neighbours per trip (each trip costs lane-mask bookkeeping)
                while (any(bits != vec2<u32>(0u))) {
                    let k1 = pop_bit(&bits);
                    let k2 = pop_bit(&bits);
                    PAIR[[j0 + k1.x]];
                    if (k2.y != 0u) { PAIR[[j0 + k2.x]]; }
                }
                for (var j = j0 + nb; j < j1; j++) { PAIR[[j]]; }
//!walls
                if (SKIP_WALLS[[an.c.y + dy]]) { continue; }
                let we = e - vec2<u32>(wall_shift(an.c.y + dy, an.c.z + dz, grid));
                let k_end = bcell_start[we.y];
                for (var k = bcell_start[we.x]; k < k_end; k++) { WALL[[k]]; }
//!end walls
            }
        }
    }
}
//!template cells
// The whole 27 cells around cell c (the adaptive stage: no clipping, no walls), every slot of
// each; returns true at the first candidate whose PAIR says stop (false: it visited them all).
fn WALK_NAME(WALK_PARAMS, c: vec3<i32>) -> bool {
    for (var kc = 0u; kc < 27u; kc++) {
        let e = cell_entries(c, kc, grid);
        if (e.x == e.y) { continue; }
        let k_end = cell_start[e.y];
        for (var k = cell_start[e.x]; k < k_end; k++) {
            if (PAIR[[k]]) { return true; }
        }
    }
    return false;
}
//!template cells_shared
// The 27 cells of `cells` as adaptive_merge.wgsl's workgroup tabulated them (nb_start, nb_pre),
// thread t's share: the candidates whose neighbourhood order is t mod WG_PARTICLES
// (`first_candidate`); PAIR may name the candidate's cell `kc`. Returns true at the first
// candidate whose PAIR says stop.
fn WALK_NAME(WALK_PARAMS, t: u32) -> bool {
    for (var kc = 0u; kc < 27u; kc++) {
        let stop = nb_start[kc] + (nb_pre[kc + 1u] - nb_pre[kc]);
        for (var k = first_candidate(kc, t); k < stop; k += WG_PARTICLES) {
            if (PAIR[[k]]) { return true; }
        }
    }
    return false;
}
