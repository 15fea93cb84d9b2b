// The 27-cell neighbour walks, one template for every pair function (src/gpu/shaders.rs
// `WALKS` names each use; a stage's line `//!walk NAME` becomes the function NAME). Words:
// WALK_NAME the function, WALK_A and WALK_ACC the accumulator's name and type, WALK_ME the
// particle's type and any further parameters; PAIR[[j]] and WALL[[k]] the calls for a fluid
// candidate j and a wall particle k, SKIP_WALLS[[y]] whether the walls' row at cell row y is out
// of the particle's reach. A use without walls leaves the //!walls block out.
//!template scan
// The search around the particle's position (no mask): the candidates of the 9 rows of slices
// around its cell, then the walls' rows.
fn WALK_NAME(WALK_A: ptr<function, WALK_ACC>, me: WALK_ME) {
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
//!template masked
// The neighbours the first compute_lambda recorded (pbf.wgsl "neighbour mask"): the same rows
// around the anchor, each row's set bits, then its candidates past the mask, then the walls.
fn WALK_NAME(WALK_A: ptr<function, WALK_ACC>, me: WALK_ME, an: Anchor, m: Mask) {
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
