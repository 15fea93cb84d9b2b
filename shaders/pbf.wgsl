// Position Based Fluids (Macklin & Mueller 2013) per substep, with per-particle radii and masses
// (level l: h = h0 2^(-l/3), m = m0 2^(-l)) through the symmetric kernels of eq. 19, and the
// floor/ceiling boundary particles counting in the density with the fluid particle's mass (eq. 18).
// Entry points, in order: predict, then per iteration compute_lambda (pred -> scratch; the
// first iteration's also builds the neighbour mask, later ones are compute_lambda_masked) and
// compute_delta (scratch -> pred), then update_velocity, vorticity (when enabled),
// viscosity_confine, finish_positions (x = p*).
//
// Neighbour mask: like Macklin's PBF and SPlisHSPlasH, a substep's density iterations use the
// neighbour set of its first compute_lambda (pairs closer than h0 then; pairs that come closer
// later are not added, pairs that leave get zero kernels). The first compute_lambda walks the
// candidates of 9 rows of slices clipped around the particle's sub-cell (integer geometry, so
// every pass enumerates the same candidates in the same order) and sets one bit per candidate
// in range; the later passes visit only the set bits. The mask lives in memory that is dead
// between predict and update_velocity: vel (128 bits), pred.w (32) and pos.w (17 bits of
// anchor, 15 of mask). Candidates past the mask's 175 bits are tested as before, in every pass.
// Mirror: src/sim/reference/pbf.rs (same names).
//!include shared/common.wgsl

struct PbfParams {
    dt: f32,
    inv_dt: f32,
    rest_density: f32,
    m0: f32,
    h0: f32,
    // relaxation epsilon of eq. 4 in 1/m^2 (config value / h0^2)
    eps: f32,
    scorr_k: f32,
    // (the kernels use SCORR_N, the same exponent as a pipeline constant)
    scorr_n: f32,
    scorr_dq: f32,
    xsph: f32,
    vorticity: f32,
    gravity: f32,
    max_speed: f32,
    // 1: the walls push along y alone (domain.free_slip). (live.single_level, 1 while every
    // particle is on level 0, lets the pair terms skip the level look-up and the per-level
    // kernel pairs: eq. 19 of equal radii is W.)
    free_slip: u32,
    // under-density up to this fraction is left alone (solver.expansion_tolerance)
    expansion_tolerance: f32,
    // the share of that correction split particles get (solver.split_expansion_weight)
    split_expansion_weight: f32,
    // per level l: (h_l, poly6 factor 315/(64 pi h^9), spiky factor -45/(pi h^6), m_l): no pow or
    // exp2 per neighbour pair (the dominant cost on CPU Vulkan)
    lv: array<vec4<f32>, MAX_LEVEL + 1u>,
}

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> prm: PbfParams;
// positions x at the start of the substep; vorticity omega (xyz, |omega|) after update_velocity
@group(0) @binding(2) var<storage, read_write> pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> vel: array<vec4<f32>>;
// predicted positions p* (compute_delta writes the corrected ones here)
@group(0) @binding(4) var<storage, read_write> pred: array<vec4<f32>>;
// compute_lambda's output (p*, lambda) that compute_delta reads: the position and the lambda of a
// neighbour in one load, and no copy back per iteration; viscosity_confine's new v
@group(0) @binding(5) var<storage, read_write> scratch: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> density: array<f32>;
// read-only bindings (declared so, the compiler need not assume they alias the written ones)
@group(0) @binding(7) var<storage, read> info: array<vec2<u32>>;
@group(0) @binding(8) var<storage, read> cell_start: array<u32>;
// boundary particles: xyz, w = temperature; cell-ordered with their own table
@group(0) @binding(9) var<storage, read> bpos: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> bcell_start: array<u32>;
@group(0) @binding(11) var<storage, read> live: Live;

// The uniforms the pair terms use, read once per invocation and passed along: read where they are
// used, inside the neighbour loops, they made the block bench's PBF 5-12% slower on llvmpipe
// (docs/PERFORMANCE.md "PBF / Session 12").
struct K {
    h0: f32,
    h0sq: f32,
    rho0: f32,
    // level 0's kernel row (prm.lv[0]): the walls', and every particle's while all are level 0
    lv0: vec4<f32>,
    scorr_k: f32,
    scorr_dq: f32,
    // live.single_level
    single: bool,
    image: Image,
}
fn pass_consts() -> K {
    return K(prm.h0, prm.h0 * prm.h0, prm.rest_density, prm.lv[0], prm.scorr_k, prm.scorr_dq,
        live.single_level != 0u, image_of(grid));
}

fn level_of(i: u32) -> u32 {
    return min(info[i].y, MAX_LEVEL);
}
// Level constants by constant-index reads and selects: a per-lane indexed read of the table is a
// scalar loop over the SIMD lanes on llvmpipe, a select chain is 7 vector ops.
fn lv_of(l: u32) -> vec4<f32> {
    var v = prm.lv[0];
    v = select(v, prm.lv[1], l == 1u);
    v = select(v, prm.lv[2], l == 2u);
    v = select(v, prm.lv[3], l == 3u);
    v = select(v, prm.lv[4], l == 4u);
    v = select(v, prm.lv[5], l == 5u);
    v = select(v, prm.lv[6], l == 6u);
    v = select(v, prm.lv[MAX_LEVEL], l >= MAX_LEVEL);
    return v;
}
// poly6 and spiky gradient of a level from its table row lv = lv_of(l) (same values as
// common.wgsl's poly6/spiky_grad), branch free (divergent branches cost both sides on SIMD CPUs
// anyway). Callers look each row up once per particle, not per pair.
fn w_lv(r2: f32, lv: vec4<f32>) -> f32 {
    let d = max(lv.x * lv.x - r2, 0.0);
    return lv.y * d * d * d;
}
fn gw_lv(xij: vec3<f32>, r: f32, lv: vec4<f32>) -> vec3<f32> {
    let d = lv.x - r;
    return select((lv.z * d * d / r) * xij, vec3<f32>(0.0), r >= lv.x || r <= 1e-9 * lv.x);
}
// eq. 19 (0.5 (a + a) == a exactly, so equal levels need no branch)
fn wsym(r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> f32 {
    return 0.5 * (w_lv(r2, lvi) + w_lv(r2, lvj));
}
fn gsym(xij: vec3<f32>, r: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> vec3<f32> {
    return 0.5 * (gw_lv(xij, r, lvi) + gw_lv(xij, r, lvj));
}

// Periodic wrap in x/z (velocity untouched) and the walls at y = 0 and y = size.
fn confine(p: vec3<f32>) -> vec3<f32> {
    var q = p;
    let s = grid.domain_size;
    if ((grid.periodic & 1u) != 0u) {
        q.x = q.x - s.x * floor(q.x / s.x);
        if (q.x >= s.x) { q.x = 0.0; }
    } else {
        q.x = clamp(q.x, 0.0, s.x);
    }
    if ((grid.periodic & 4u) != 0u) {
        q.z = q.z - s.z * floor(q.z / s.z);
        if (q.z >= s.z) { q.z = 0.0; }
    } else {
        q.z = clamp(q.z, 0.0, s.z);
    }
    q.y = clamp(q.y, 0.0, s.y);
    return q;
}

fn clamp_speed(v: vec3<f32>) -> vec3<f32> {
    let s = length(v);
    if (s > prm.max_speed) { return v * (prm.max_speed / s); }
    return v;
}

@compute @workgroup_size(WG_PARTICLES)
fn predict(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    var v = vel[i].xyz;
    v.y = v.y - prm.gravity * prm.dt;
    v = clamp_speed(v);
    pred[i] = vec4<f32>(confine(pos[i].xyz + v * prm.dt), 0.0);
}

// The s_corr exponent n in [1, 16] (validated), `solver.scorr_n`: a pipeline constant (the stage
// sets it from PbfParams.scorr_n), so pow_n compiles to its squarings alone. Read from the
// uniform, the exponent and its select chain cost 27% of a density iteration of the periodic
// bench on llvmpipe (docs/PERFORMANCE.md "PBF / Session 12").
override SCORR_N: u32;

// x^n for the s_corr exponent by squaring: no loop per pair (a loop inside the pair loop costs
// its own mask bookkeeping on SIMD CPUs).
fn pow_n(x: f32) -> f32 {
    let n = SCORR_N;
    var t = select(1.0, x, (n & 1u) != 0u);
    var b = x * x;
    t = select(t, t * b, (n & 2u) != 0u);
    b = b * b;
    t = select(t, t * b, (n & 4u) != 0u);
    b = b * b;
    t = select(t, t * b, (n & 8u) != 0u);
    b = b * b;
    return select(t, t * b, (n & 16u) != 0u);
}

// Artificial pressure s_corr = -k (W / W(dq h))^n h_i h_j (k dimensionless; h_i h_j gives lambda's
// units, m^2, so the term is scale free).
fn scorr(k: K, r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> f32 {
    if (k.scorr_k == 0.0) { return 0.0; }
    let hi = lvi.x;
    let hj = lvj.x;
    let hb = k.scorr_dq * 0.5 * (hi + hj);
    let x = wsym(r2, lvi, lvj) / wsym(hb * hb, lvi, lvj);
    let t = pow_n(x);
    return -k.scorr_k * t * hi * hj;
}

struct LamAcc {
    grad: vec3<f32>,
    rho: f32,
    g2: f32,
    // a wall particle is within the kernel
    near_wall: bool,
}
struct Me {
    p: vec3<f32>,
    li: u32,
    lv: vec4<f32>,
    hi: f32,
    mi: f32,
    lam: f32,
    wdq: f32,
    k: K,
}
// Particle i at position and lambda pl (pred[i] with 0 in compute_lambda, scratch[i] after it)
fn me_of(i: u32, pl: vec4<f32>) -> Me {
    let li = level_of(i);
    let lv = lv_of(li);
    let hd = prm.scorr_dq * lv.x;
    return Me(pl.xyz, li, lv, lv.x, lv.w, pl.w, w_lv(hd * hd, lv), pass_consts());
}
// Level-0 kernels from the table's first row.
fn w0(r2: f32, k: K) -> f32 {
    return w_lv(r2, k.lv0);
}
fn gw0(xij: vec3<f32>, r: f32, k: K) -> vec3<f32> {
    return gw_lv(xij, r, k.lv0);
}
// Adds candidate j; returns whether it is closer than h0 (a neighbour for the mask). `packed`:
// j's level comes from the top bits of pred[j].w (`store_mask`, multi-level only), loaded with its
// position; the first compute_lambda, which writes pred.w, reads it from `info`.
fn lam_fluid(a: ptr<function, LamAcc>, me: Me, j: u32, packed: bool) -> bool {
    let k = me.k;
    if (k.single) {
        let xij = min_image_by_reciprocal(me.p - pred[j].xyz, k.image);
        let r2 = dot(xij, xij);
        // no branch: both kernels are exactly 0 beyond h0 (adding 0 changes no sum), and on SIMD
        // CPUs a branch costs lane-mask bookkeeping for every pair
        let m = k.lv0.w;
        (*a).rho += m * w0(r2, k);
        let g = gw0(xij, sqrt(r2), k) * (m / k.rho0);
        (*a).grad += g;
        (*a).g2 += dot(g, g);
        return r2 < k.h0sq;
    }
    let pj = pred[j];
    let xij = min_image_by_reciprocal(me.p - pj.xyz, k.image);
    let r2 = dot(xij, xij);
    // every radius is <= h0: farther pairs are rejected before their level is looked up
    if (r2 < k.h0sq) {
        var lj: u32;
        if (packed) { lj = packed_level(pj.w); } else { lj = level_of(j); }
        let lvj = lv_of(lj);
        let hm = max(me.hi, lvj.x);
        if (r2 < hm * hm) {
            let mj = lvj.w;
            (*a).rho += mj * wsym(r2, me.lv, lvj);
            let g = gsym(xij, sqrt(r2), me.lv, lvj) * (mj / k.rho0);
            (*a).grad += g;
            (*a).g2 += dot(g, g);
        }
        return true;
    }
    return false;
}
// A wall particle's kernel gradient; with free slip its normal (y) part alone. The walls are
// a lattice at rest: the sideways part of their push drags the air sliding over them towards
// the shot's frame, and is the one term of the solver that does not keep the momentum.
fn wall_grad(g: vec3<f32>) -> vec3<f32> {
    if (prm.free_slip != 0u) { return vec3<f32>(0.0, g.y, 0.0); }
    return g;
}
// Wall particles continue the level-0 lattice and weigh m0 whatever the fluid particle's level
// (eq. 18 with the fluid's own mass starved split particles: a level-3 particle got 0.07 rho0
// from the wall instead of 0.5 and was never pushed off it).
fn lam_wall(a: ptr<function, LamAcc>, me: Me, k: u32) {
    let c = me.k;
    let xik = min_image_by_reciprocal(me.p - bpos[k].xyz, c.image);
    let r2 = dot(xik, xik);
    let hm = max(me.hi, c.h0);
    if (r2 < hm * hm) {
        let m = c.lv0.w;
        (*a).rho += m * wsym(r2, me.lv, c.lv0);
        (*a).grad += wall_grad(gsym(xik, sqrt(r2), me.lv, c.lv0)) * (m / c.rho0);
        (*a).near_wall = true;
    }
}

// The old search around the current position (no mask): particles whose substep moved them more
// than a cell from their start (no anchor).
//!walk lam_scan

// ---- neighbour mask ----
// Sub-cell units per cell edge; cells are >= h0, so boxes at least SUB units apart (per-axis
// units) are at least h0 apart.
const SUB: i32 = 16;
const META_BITS: u32 = 17u;
const NO_ANCHOR: u32 = 31u;
// 128 bits in vel, 32 in pred.w, 15 in pos.w above the anchor
const MASK_BITS: u32 = 175u;
// With more than one level, pred.w's top 3 bits carry the particle's level, so the passes after
// the first gather a neighbour's level with its position instead of from `info` (one load per
// neighbour fewer), and the mask has 3 bits fewer: words 4 and 5 are pred.w's low 29 bits and
// pos.w's 15 (`mask_of`, `store_mask`).
const LEVEL_SHIFT: u32 = 29u;
const MASK_BITS_MULTI: u32 = 172u;

struct Anchor {
    c: vec3<i32>,
    s: vec3<i32>,
    ok: bool,
}
// Mask bits 0-127, 128-159 and 160-174 (160-171 with more than one level) as words.
struct Mask {
    w: vec4<u32>,
    w4: u32,
    w5: u32,
}

// The anchor of p* (its cell as an offset -1..1 from the cell of x, the position at the start of
// the substep, which does not change during the iterations; and its 1/16-cell sub-cell):
// code (dx + 1) + 3 (dy + 1) + 9 (dz + 1) in bits 0-4 (31: more than a cell away), sub-cell
// x, y, z in bits 5-8, 9-12, 13-16.
fn anchor_meta(x: vec3<f32>, p: vec3<f32>) -> u32 {
    let cx = cell_coord(x, grid);
    let cp = cell_coord(p, grid);
    var dc = cp - cx;
    let d = vec3<i32>(grid.dims);
    if ((grid.periodic & 1u) != 0u) { dc.x = (dc.x + 1 + d.x) % d.x - 1; }
    if ((grid.periodic & 4u) != 0u) { dc.z = (dc.z + 1 + d.z) % d.z - 1; }
    if (any(abs(dc) > vec3<i32>(1))) { return NO_ANCHOR; }
    let f = (p - grid.domain_min - vec3<f32>(cp) * grid.cell_size) / grid.cell_size;
    let s = clamp(vec3<i32>(floor(f * f32(SUB))), vec3<i32>(0), vec3<i32>(SUB - 1));
    let code = u32((dc.x + 1) + 3 * (dc.y + 1) + 9 * (dc.z + 1));
    return code | (u32(s.x) << 5u) | (u32(s.y) << 9u) | (u32(s.z) << 13u);
}
fn anchor_of(x: vec3<f32>, tag: u32) -> Anchor {
    let code = tag & 31u;
    if (code == NO_ANCHOR) { return Anchor(vec3<i32>(0), vec3<i32>(0), false); }
    let dc = vec3<i32>(i32(code % 3u), i32((code / 3u) % 3u), i32(code / 9u)) - vec3<i32>(1);
    var c = cell_coord(x, grid) + dc;
    let d = vec3<i32>(grid.dims);
    if ((grid.periodic & 1u) != 0u) { c.x = wrap(c.x, d.x); }
    if ((grid.periodic & 4u) != 0u) { c.z = wrap(c.z, d.z); }
    let s = vec3<i32>(i32((tag >> 5u) & 15u), i32((tag >> 9u) & 15u), i32((tag >> 13u) & 15u));
    return Anchor(c, s, true);
}

// Row (dy, dz) around the anchor, clipped to the slices within SUB units of its sub-cell (all
// integers: every pass gets the same entries); the entry ranges as `row_entries`.
fn anchor_row(an: Anchor, dy: i32, dz: i32) -> vec4<u32> {
    let none = vec4<u32>(0u);
    let d = vec3<i32>(grid.dims);
    let ny = an.c.y + dy;
    if (ny < 0 || ny >= d.y) { return none; }
    var nz = an.c.z + dz;
    if ((grid.periodic & 4u) != 0u) { nz = wrap(nz, d.z); } else if (nz < 0 || nz >= d.z) { return none; }
    // gaps in units between the sub-cell [s, s + 1] and the row's cell [k SUB, (k + 1) SUB]
    let gy = max(max(dy * SUB - (an.s.y + 1), an.s.y - (dy + 1) * SUB), 0);
    let gz = max(max(dz * SUB - (an.s.z + 1), an.s.z - (dz + 1) * SUB), 0);
    let rem = SUB * SUB - gy * gy - gz * gz;
    if (rem <= 0) { return none; }
    // slices k (units [k wu, (k + 1) wu] from the row's first cell) with gap gx^2 < rem, i.e.
    // gx <= r = isqrt(rem - 1) (f32 sqrt, corrected to the exact integer)
    var r = i32(sqrt(f32(rem - 1)));
    if ((r + 1) * (r + 1) <= rem - 1) { r += 1; }
    if (r * r > rem - 1) { r -= 1; }
    let xs = i32(grid.x_slices);
    // slice width SUB / x_slices, a power of two (by bit positions: an integer division by a
    // buffer value is a scalar divide per lane on SIMD CPUs)
    let sh = firstTrailingBit(u32(SUB)) - firstTrailingBit(grid.x_slices);
    let sx = an.s.x + SUB;
    let a = max(((sx - r + (1 << sh) - 1) >> sh) - 1, 0);
    let b = min((sx + 1 + r) >> sh, 3 * xs - 1);
    let x0 = (an.c.x - 1) * xs;
    return row_span(nz, ny, x0 + a, x0 + b, grid);
}

fn low_bits(n: u32) -> u32 {
    return select((1u << n) - 1u, 0xffffffffu, n >= 32u);
}
// Word k of a mask by selects (a per-lane indexed read is a scalar loop on SIMD CPUs).
fn mask_word(m: Mask, k: u32) -> u32 {
    var r = select(0u, m.w.x, k == 0u);
    r = select(r, m.w.y, k == 1u);
    r = select(r, m.w.z, k == 2u);
    r = select(r, m.w.w, k == 3u);
    r = select(r, m.w4, k == 4u);
    return select(r, m.w5, k == 5u);
}
// nb (<= 64) bits of the mask from bit `off`
fn mask_get(m: Mask, off: u32, nb: u32) -> vec2<u32> {
    if (nb == 0u) { return vec2<u32>(0u); }
    let wi = off >> 5u;
    let sh = off & 31u;
    let b = mask_word(m, wi + 1u);
    var lo = mask_word(m, wi) >> sh;
    var hi = b >> sh;
    if (sh != 0u) {
        lo |= b << (32u - sh);
        hi |= mask_word(m, wi + 2u) << (32u - sh);
    }
    return vec2<u32>(lo & low_bits(min(nb, 32u)), hi & low_bits(max(nb, 32u) - 32u));
}
fn mask_put(m: ptr<function, Mask>, off: u32, bits: vec2<u32>, nb: u32) {
    let lo = bits.x & low_bits(min(nb, 32u));
    let hi = bits.y & low_bits(max(nb, 32u) - 32u);
    let wi = off >> 5u;
    let sh = off & 31u;
    let va = lo << sh;
    var vb = hi << sh;
    var vc = 0u;
    if (sh != 0u) {
        vb |= lo >> (32u - sh);
        vc = hi >> (32u - sh);
    }
    let k = vec4<u32>(0u, 1u, 2u, 3u);
    let z = vec4<u32>(0u);
    (*m).w |= select(z, vec4<u32>(va), k == vec4<u32>(wi)) | select(z, vec4<u32>(vb), k == vec4<u32>(wi + 1u))
        | select(z, vec4<u32>(vc), k == vec4<u32>(wi + 2u));
    (*m).w4 |= select(0u, va, wi == 4u) | select(0u, vb, wi + 1u == 4u) | select(0u, vc, wi + 2u == 4u);
    (*m).w5 |= select(0u, va, wi == 5u) | select(0u, vb, wi + 1u == 5u) | select(0u, vc, wi + 2u == 5u);
}
// Mask bits a segment of n candidates starting at bit `off` has (the rest are tested each pass).
fn seg_bits(off: u32, n: u32, single: bool) -> u32 {
    let cap = select(MASK_BITS_MULTI, MASK_BITS, single);
    return min(min(n, 64u), cap - min(off, cap));
}
// Where the first compute_lambda leaves the mask: words 0-3 in vel; all level 0, word 4 in pred.w
// and word 5 (15 bits) above the anchor in pos.w; otherwise pred.w = word 4's low 29 bits and
// the level li on top, pos.w = the anchor and word 4's top 3 bits and word 5's 12 (mask_put never
// sets a bit past MASK_BITS_MULTI then). Returns (pred.w, pos.w).
fn store_mask(m: Mask, li: u32, tag: u32, single: bool) -> vec2<f32> {
    let low = (1u << LEVEL_SHIFT) - 1u;
    let pw = select((m.w4 & low) | (li << LEVEL_SHIFT), m.w4, single);
    let hi = select((m.w4 >> LEVEL_SHIFT) | (m.w5 << 3u), m.w5, single);
    return vec2<f32>(bitcast<f32>(pw), bitcast<f32>(tag | (hi << META_BITS)));
}
// The level in pred.w (more than one level only).
fn packed_level(w: f32) -> u32 {
    return bitcast<u32>(w) >> LEVEL_SHIFT;
}
// The mask from vel, pred.w and pos.w (`store_mask`).
fn mask_of(v: vec4<f32>, pw: f32, tag: u32, single: bool) -> Mask {
    let p = bitcast<u32>(pw);
    let hi = tag >> META_BITS;
    let low = (1u << LEVEL_SHIFT) - 1u;
    let w4 = select((p & low) | (hi << LEVEL_SHIFT), p, single);
    let w5 = select(hi >> 3u, hi, single);
    return Mask(bitcast<vec4<u32>>(v), w4, w5);
}

// Takes the lowest set bit of a row's 64-bit mask: (candidate offset, whether there was one).
fn pop_bit(bits: ptr<function, vec2<u32>>) -> vec2<u32> {
    let b = *bits;
    let lo = b.x != 0u;
    let w = select(b.y, b.x, lo);
    *bits = select(vec2<u32>(b.x, w & (w - 1u)), vec2<u32>(w & (w - 1u), b.y), lo);
    return vec2<u32>(select(32u, 0u, lo) + firstTrailingBit(w), u32(w != 0u));
}

// First iteration: lambda over the anchor's candidates, recording the neighbours (closer than h0).
//!walk lam_build
//!walk lam_masked

// The first iteration's lambda: builds the neighbour mask (vel, pred.w, pos.w; pred.w alone,
// the other threads read only pred's xyz) and, with more than one level, puts the level into
// pred.w.
@compute @workgroup_size(WG_PARTICLES)
fn compute_lambda(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let me = me_of(i, vec4<f32>(pred[i].xyz, 0.0));
    var a = LamAcc(vec3<f32>(0.0), 0.0, 0.0, false);
    let x = pos[i].xyz;
    let tag = anchor_meta(x, me.p);
    let an = anchor_of(x, tag);
    var m = Mask(vec4<u32>(0u), 0u, 0u);
    if (an.ok) {
        m = lam_build(&a, me, an);
    } else {
        lam_scan(&a, me, false);
    }
    vel[i] = bitcast<vec4<f32>>(m.w);
    let st = store_mask(m, me.li, tag, me.k.single);
    pred[i].w = st.x;
    pos[i] = vec4<f32>(x, st.y);
    lambda_out(i, me, a);
}

// Later iterations' lambda (and the density pass after them): the mask's neighbours.
@compute @workgroup_size(WG_PARTICLES)
fn compute_lambda_masked(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let pi = pred[i];
    let me = me_of(i, vec4<f32>(pi.xyz, 0.0));
    var a = LamAcc(vec3<f32>(0.0), 0.0, 0.0, false);
    let xm = pos[i];
    let tag = bitcast<u32>(xm.w);
    let an = anchor_of(xm.xyz, tag);
    if (an.ok) {
        lam_masked(&a, me, an, mask_of(vel[i], pi.w, tag, me.k.single));
    } else {
        lam_scan(&a, me, true);
    }
    lambda_out(i, me, a);
}

fn lambda_out(i: u32, me: Me, a: LamAcc) {
    // Unilateral density constraint (compression only). With C < 0 allowed, an under-dense
    // neighbourhood gives lambda > 0, which pulls pairs together hardest where the spiky gradient
    // is largest, at small r: pairs collapse and accelerate into each other (measured: a box at
    // rest without gravity reached the 30 m/s speed clamp within 2 s whatever the relaxation).
    // Air parcels do not pull on each other; s_corr keeps its small repulsion.
    var constraint = a.rho / prm.rest_density - 1.0;
    if (constraint < 0.0) {
        constraint = min(constraint + prm.expansion_tolerance, 0.0);
        // Split particles get a share of it: their eq. 19 density is noisy next to coarser
        // neighbours; pulled in fully they clump (particles at the speed clamp in quickstart),
        // not at all they sit 2.7% under-dense (quickstart frame 48, level 3). Next to a wall,
        // none: a pulled split particle is held on the clamp plane.
        var w = prm.split_expansion_weight;
        if (a.near_wall) { w = 0.0; }
        if (me.li > 0u) { constraint = constraint * w; }
    }
    let lam = -constraint / (a.g2 + dot(a.grad, a.grad) + prm.eps);
    scratch[i] = vec4<f32>(me.p, lam_pack(lam, me.li, me.k.single));
    density[i] = a.rho;
}

// With more than one level, lambda's 3 low mantissa bits carry the particle's level from the
// lambda passes to the delta passes, which then gather a neighbour's level with its lambda
// instead of loading info[j] (lambda loses 3 bits: under 1e-6 of itself). One level: lambda whole.
const LAM_LEVEL_MASK: u32 = 7u;
const_assert MAX_LEVEL <= LAM_LEVEL_MASK;
fn lam_pack(lam: f32, li: u32, single: bool) -> f32 {
    return select(bitcast<f32>((bitcast<u32>(lam) & ~LAM_LEVEL_MASK) | li), lam, single);
}
fn lam_value(w: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(w) & ~LAM_LEVEL_MASK);
}
fn lam_level(w: f32) -> u32 {
    return bitcast<u32>(w) & LAM_LEVEL_MASK;
}

// s_corr with W(dq h_i) precomputed for same-level pairs
fn scorr_me(me: Me, r2: f32, lj: u32, lvj: vec4<f32>) -> f32 {
    if (lj != me.li) { return scorr(me.k, r2, me.lv, lvj); }
    if (me.k.scorr_k == 0.0) { return 0.0; }
    let x = w_lv(r2, me.lv) / me.wdq;
    let t = pow_n(x);
    return -me.k.scorr_k * t * me.hi * me.hi;
}
fn delta_fluid(dp: ptr<function, vec3<f32>>, me: Me, j: u32) {
    let k = me.k;
    let pj = scratch[j];
    let xij = min_image_by_reciprocal(me.p - pj.xyz, k.image);
    let r2 = dot(xij, xij);
    if (k.single) {
        // no branch (see lam_fluid): gw0 is exactly 0 beyond h0
        let m = k.lv0.w;
        var sc = 0.0;
        if (k.scorr_k != 0.0) {
            let x = w0(r2, k) / me.wdq;
            sc = -k.scorr_k * pow_n(x) * me.hi * me.hi;
        }
        let s = me.lam * m + pj.w * me.mi + sc * m;
        *dp += s * gw0(xij, sqrt(r2), k);
        return;
    }
    if (r2 < k.h0sq) {
        let lj = lam_level(pj.w);
        let lvj = lv_of(lj);
        let hm = max(me.hi, lvj.x);
        if (r2 < hm * hm) {
            let mj = lvj.w;
            let s = me.lam * mj + lam_value(pj.w) * me.mi + scorr_me(me, r2, lj, lvj) * mj;
            *dp += s * gsym(xij, sqrt(r2), me.lv, lvj);
        }
    }
}
fn delta_wall(dp: ptr<function, vec3<f32>>, me: Me, k: u32) {
    let c = me.k;
    let xik = min_image_by_reciprocal(me.p - bpos[k].xyz, c.image);
    let r2 = dot(xik, xik);
    let hm = max(me.hi, c.h0);
    if (r2 < hm * hm) {
        let s = (me.lam + scorr(c, r2, me.lv, c.lv0)) * c.lv0.w;
        *dp += s * wall_grad(gsym(xik, sqrt(r2), me.lv, c.lv0));
    }
}

//!walk delta_scan
//!walk delta_masked

// Position correction over the mask's neighbours (every compute_delta follows a compute_lambda
// of the same substep).
@compute @workgroup_size(WG_PARTICLES)
fn compute_delta(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    var me = me_of(i, scratch[i]);
    if (!me.k.single) { me.lam = lam_value(me.lam); }
    var dp = vec3<f32>(0.0);
    let xm = pos[i];
    let tag = bitcast<u32>(xm.w);
    let an = anchor_of(xm.xyz, tag);
    let w4 = pred[i].w;
    if (an.ok) {
        delta_masked(&dp, me, an, mask_of(vel[i], w4, tag, me.k.single));
    } else {
        delta_scan(&dp, me);
    }
    // pred.w: the mask's word 4 (and the level), kept
    pred[i] = vec4<f32>(confine(me.p + dp / prm.rest_density), w4);
}

@compute @workgroup_size(WG_PARTICLES)
fn update_velocity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    // v and the density into the scratch (free after the last compute_lambda), so that the
    // velocity passes gather a neighbour's v and rho with one load: vel still holds the mask,
    // which viscosity_confine reads before it writes the final velocity there. The height
    // gained in this substep (eq. 7's adiabatic cooling, thermo.wgsl) waits in `density`, which
    // only particle i reads from here on.
    let d = min_image(pred[i].xyz - pos[i].xyz, grid);
    scratch[i] = vec4<f32>(d * prm.inv_dt, density[i]);
    density[i] = d.y;
}

// Pair terms of the velocity passes for a candidate j with r2 < h0^2: j's level constants and
// whether r < max(h_i, h_j). All level 0: the table's first row, no level look-up.
struct Pair {
    inside: bool,
    lvj: vec4<f32>,
}
fn pair_of(k: K, r2: f32, hi: f32, j: u32) -> Pair {
    if (k.single) { return Pair(true, k.lv0); }
    return pair_at(k, r2, hi, level_of(j));
}
// The same for a level already known (more than one level).
fn pair_at(k: K, r2: f32, hi: f32, lj: u32) -> Pair {
    let lvj = lv_of(lj);
    let hm = max(hi, lvj.x);
    return Pair(r2 < hm * hm, lvj);
}
// W and grad W of eq. 19 (level 0 alone: the same values without the per-level selects)
fn pair_w(k: K, r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> f32 {
    if (k.single) { return w0(r2, k); }
    return wsym(r2, lvi, lvj);
}
fn pair_g(k: K, xij: vec3<f32>, r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> vec3<f32> {
    if (k.single) { return gw0(xij, sqrt(r2), k); }
    return gsym(xij, sqrt(r2), lvi, lvj);
}

// omega_i = sum_j V_j (v_i - v_j) x grad_i W_ij, V_j = m_j / rho_j; written over pos (x is dead).
// The particle: its predicted position, velocity (the scratch's, update_velocity) and level row.
struct Vo {
    p: vec3<f32>,
    v: vec3<f32>,
    lv: vec4<f32>,
    k: K,
}
fn vort_pair(w: ptr<function, vec3<f32>>, me: Vo, j: u32) {
    let k = me.k;
    let xij = min_image_by_reciprocal(me.p - pred[j].xyz, k.image);
    let r2 = dot(xij, xij);
    // every radius is <= h0: pairs beyond it are rejected before their level is loaded
    if (r2 >= k.h0sq) { return; }
    let pk = pair_of(k, r2, me.lv.x, j);
    if (!pk.inside) { return; }
    let lvj = pk.lvj;
    let sj = scratch[j];
    let vj = lvj.w / sj.w;
    *w += vj * cross(me.v - sj.xyz, pair_g(k, xij, r2, me.lv, pk.lvj));
}
//!walk vort_scan
@compute @workgroup_size(WG_PARTICLES)
fn vorticity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let me = Vo(pred[i].xyz, scratch[i].xyz, lv_of(level_of(i)), pass_consts());
    var w = vec3<f32>(0.0);
    vort_scan(&w, me);
    pos[i] = vec4<f32>(w, length(w));
}

// XSPH viscosity v_i += c sum_j 2 m_j / (rho_i + rho_j) (v_j - v_i) W_ij and vorticity confinement
// a = eps (N x omega_i), N = eta / |eta|, eta = sum_j V_j (|omega_j| - |omega_i|) grad_i W_ij;
// then the speed clamp. Reads v from the scratch (update_velocity), writes the new v to vel, and
// sums the density at the corrected positions over the same pairs and the walls (what one more
// compute_lambda would measure: the frame's density, the splat's m / rho).
// Without vorticity the pairs are the mask's (vorticity writes omega over pos, and the anchor).
struct Visc {
    acc: vec3<f32>,
    eta: vec3<f32>,
    // the density at the corrected positions (compute_lambda's sum over the same pairs)
    rho: f32,
}
struct Vi {
    p: vec3<f32>,
    v: vec3<f32>,
    lv: vec4<f32>,
    rho: f32,
    w: f32,
    vort: bool,
    k: K,
}
fn visc_pair(a: ptr<function, Visc>, me: Vi, j: u32) {
    let k = me.k;
    // every radius is <= h0: pairs beyond it are rejected before their level is looked up
    if (k.single) {
        let xij = min_image_by_reciprocal(me.p - pred[j].xyz, k.image);
        let r2 = dot(xij, xij);
        if (r2 >= k.h0sq) { return; }
        visc_add(a, me, j, xij, r2, k.lv0);
        return;
    }
    // with more than one level, j's level comes with its position (`store_mask`)
    let pj = pred[j];
    let xij = min_image_by_reciprocal(me.p - pj.xyz, k.image);
    let r2 = dot(xij, xij);
    if (r2 >= k.h0sq) { return; }
    let pk = pair_at(k, r2, me.lv.x, packed_level(pj.w));
    if (!pk.inside) { return; }
    visc_add(a, me, j, xij, r2, pk.lvj);
}
// The XSPH, density and vorticity terms of a pair within reach (level constants lvj).
fn visc_add(a: ptr<function, Visc>, me: Vi, j: u32, xij: vec3<f32>, r2: f32, lvj: vec4<f32>) {
    let k = me.k;
    // (v_j, rho_j)
    let sj = scratch[j];
    // 2 m_j / (rho_i + rho_j): pairwise symmetric, so XSPH conserves momentum
    let vs = 2.0 * lvj.w / (me.rho + sj.w);
    let w = pair_w(k, r2, me.lv, lvj);
    (*a).acc += vs * w * (sj.xyz - me.v);
    (*a).rho += lvj.w * w;
    if (me.vort) {
        (*a).eta += (lvj.w / sj.w) * (pos[j].w - me.w) * pair_g(k, xij, r2, me.lv, lvj);
    }
}
// A wall particle's share of the density (lam_wall's).
fn visc_wall(a: ptr<function, Visc>, me: Vi, k: u32) {
    let c = me.k;
    let xik = min_image_by_reciprocal(me.p - bpos[k].xyz, c.image);
    let r2 = dot(xik, xik);
    let hm = max(me.lv.x, c.h0);
    if (r2 < hm * hm) {
        (*a).rho += c.lv0.w * wsym(r2, me.lv, c.lv0);
    }
}
//!walk visc_scan
//!walk visc_masked
@compute @workgroup_size(WG_PARTICLES)
fn viscosity_confine(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let use_vort = prm.vorticity > 0.0;
    let vw = scratch[i];
    // the height gained in this substep (update_velocity), kept in vel.w for thermo.wgsl
    let gained = density[i];
    let xm = pos[i];
    let me = Vi(pred[i].xyz, vw.xyz, lv_of(level_of(i)), vw.w, select(0.0, xm.w, use_vort),
        use_vort, pass_consts());
    var a = Visc(vec3<f32>(0.0), vec3<f32>(0.0), 0.0);
    var an = Anchor(vec3<i32>(0), vec3<i32>(0), false);
    if (!use_vort) { an = anchor_of(xm.xyz, bitcast<u32>(xm.w)); }
    if (an.ok) {
        visc_masked(&a, me, an, mask_of(vel[i], pred[i].w, bitcast<u32>(xm.w), me.k.single));
    } else {
        visc_scan(&a, me);
    }
    var v = me.v + prm.xsph * a.acc;
    let le = length(a.eta);
    if (use_vort && le > 0.0) {
        v += prm.dt * prm.vorticity * cross(a.eta / le, xm.xyz);
    }
    vel[i] = vec4<f32>(clamp_speed(v), gained);
    // no neighbour reads density[i] here (they read rho_j from the scratch)
    density[i] = a.rho;
}

// x = p* at the end of the substep (w = 0: pos.w held the neighbour mask's anchor, or omega).
@compute @workgroup_size(WG_PARTICLES)
fn finish_positions(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    pos[i] = vec4<f32>(pred[i].xyz, 0.0);
}
