// Position Based Fluids (Macklin & Mueller 2013) per substep, with per-particle radii and masses
// (level l: h = h0 2^(-l/3), m = m0 2^(-l)) through the symmetric kernels of eq. 19, and the
// floor/ceiling boundary particles counting in the density with the fluid particle's mass (eq. 18).
// Entry points, in order: predict, then per iteration compute_lambda (pred -> scratch) and
// compute_delta (scratch -> pred), then update_velocity, vorticity (when enabled),
// viscosity_confine (+ copy).
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
    scorr_n: f32,
    scorr_dq: f32,
    xsph: f32,
    vorticity: f32,
    gravity: f32,
    max_speed: f32,
    // (live.single_level, 1 while every particle is on level 0, lets the pair terms skip the
    // level look-up and the per-level kernel pairs: eq. 19 of equal radii is W)
    _pad0: u32,
    // under-density up to this fraction is left alone (solver.expansion_tolerance)
    expansion_tolerance: f32,
    // the share of that correction split particles get (solver.split_expansion_weight)
    split_expansion_weight: f32,
    // per level l: (h_l, poly6 factor 315/(64 pi h^9), spiky factor -45/(pi h^6), m_l): no pow or
    // exp2 per neighbour pair (the dominant cost on CPU Vulkan)
    lv: array<vec4<f32>, 8>,
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

// min_image with a reciprocal (one multiply instead of a divide per pair; the rounded image is the
// same for every pair closer than half the domain, i.e. every pair that counts)
fn min_image_r(d: vec3<f32>, inv: vec3<f32>) -> vec3<f32> {
    var r = d;
    if ((grid.periodic & 1u) != 0u) { r.x = r.x - grid.domain_size.x * round(r.x * inv.x); }
    if ((grid.periodic & 4u) != 0u) { r.z = r.z - grid.domain_size.z * round(r.z * inv.z); }
    return r;
}

fn level_of(i: u32) -> u32 {
    return min(info[i].y, 7u);
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
    v = select(v, prm.lv[7], l >= 7u);
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

// x^n for the s_corr exponent n in [1, 16] (validated) by squaring: no loop per pair (a loop
// inside the pair loop costs its own mask bookkeeping on SIMD CPUs).
fn pow_n(x: f32) -> f32 {
    let n = u32(prm.scorr_n);
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
fn scorr(r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> f32 {
    if (prm.scorr_k == 0.0) { return 0.0; }
    let hi = lvi.x;
    let hj = lvj.x;
    let hb = prm.scorr_dq * 0.5 * (hi + hj);
    let x = wsym(r2, lvi, lvj) / wsym(hb * hb, lvi, lvj);
    let t = pow_n(x);
    return -prm.scorr_k * t * hi * hj;
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
    inv: vec3<f32>,
    wdq: f32,
}
// Particle i at position and lambda pl (pred[i] with 0 in compute_lambda, scratch[i] after it)
fn me_of(i: u32, pl: vec4<f32>) -> Me {
    let li = level_of(i);
    let lv = lv_of(li);
    let hd = prm.scorr_dq * lv.x;
    return Me(pl.xyz, li, lv, lv.x, lv.w, pl.w, 1.0 / grid.domain_size, w_lv(hd * hd, lv));
}
// Level-0 kernels from the table's first row.
fn w0(r2: f32) -> f32 {
    return w_lv(r2, prm.lv[0]);
}
fn gw0(xij: vec3<f32>, r: f32) -> vec3<f32> {
    return gw_lv(xij, r, prm.lv[0]);
}
fn lam_fluid(a: ptr<function, LamAcc>, me: Me, j: u32) {
    let xij = min_image_r(me.p - pred[j].xyz, me.inv);
    let r2 = dot(xij, xij);
    if (live.single_level != 0u) {
        if (r2 < prm.h0 * prm.h0) {
            let m = prm.lv[0].w;
            (*a).rho += m * w0(r2);
            let g = gw0(xij, sqrt(r2)) * (m / prm.rest_density);
            (*a).grad += g;
            (*a).g2 += dot(g, g);
        }
        return;
    }
    // every radius is <= h0: farther pairs are rejected before their level is loaded
    if (r2 < prm.h0 * prm.h0) {
        let lj = level_of(j);
        let lvj = lv_of(lj);
        let hm = max(me.hi, lvj.x);
        if (r2 < hm * hm) {
            let mj = lvj.w;
            (*a).rho += mj * wsym(r2, me.lv, lvj);
            let g = gsym(xij, sqrt(r2), me.lv, lvj) * (mj / prm.rest_density);
            (*a).grad += g;
            (*a).g2 += dot(g, g);
        }
    }
}
// Wall particles continue the level-0 lattice and weigh m0 whatever the fluid particle's level
// (eq. 18 with the fluid's own mass starved split particles: a level-3 particle got 0.07 rho0
// from the wall instead of 0.5 and was never pushed off it).
fn lam_wall(a: ptr<function, LamAcc>, me: Me, k: u32) {
    let xik = min_image_r(me.p - bpos[k].xyz, me.inv);
    let r2 = dot(xik, xik);
    let hm = max(me.hi, prm.h0);
    if (r2 < hm * hm) {
        let m = prm.lv[0].w;
        (*a).rho += m * wsym(r2, me.lv, prm.lv[0]);
        (*a).grad += gsym(xik, sqrt(r2), me.lv, prm.lv[0]) * (m / prm.rest_density);
        (*a).near_wall = true;
    }
}

@compute @workgroup_size(WG_PARTICLES)
fn compute_lambda(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let me = me_of(i, vec4<f32>(pred[i].xyz, 0.0));
    var a = LamAcc(vec3<f32>(0.0), 0.0, 0.0, false);
    let c = cell_coord(me.p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = row_entries(me.p, c, dy, dz, grid);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j_end = cell_start[e.y];
                for (var j = cell_start[e.x]; j < j_end; j++) { lam_fluid(&a, me, j); }
                let k_end = bcell_start[e.y];
                for (var k = bcell_start[e.x]; k < k_end; k++) { lam_wall(&a, me, k); }
            }
        }
    }
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
    scratch[i] = vec4<f32>(me.p, -constraint / (a.g2 + dot(a.grad, a.grad) + prm.eps));
    density[i] = a.rho;
}

// s_corr with W(dq h_i) precomputed for same-level pairs
fn scorr_me(me: Me, r2: f32, lj: u32, lvj: vec4<f32>) -> f32 {
    if (lj != me.li) { return scorr(r2, me.lv, lvj); }
    if (prm.scorr_k == 0.0) { return 0.0; }
    let x = w_lv(r2, me.lv) / me.wdq;
    let t = pow_n(x);
    return -prm.scorr_k * t * me.hi * me.hi;
}
fn delta_fluid(dp: ptr<function, vec3<f32>>, me: Me, j: u32) {
    let pj = scratch[j];
    let xij = min_image_r(me.p - pj.xyz, me.inv);
    let r2 = dot(xij, xij);
    if (live.single_level != 0u) {
        if (r2 < prm.h0 * prm.h0) {
            let m = prm.lv[0].w;
            var sc = 0.0;
            if (prm.scorr_k != 0.0) {
                let x = w0(r2) / me.wdq;
                sc = -prm.scorr_k * pow_n(x) * me.hi * me.hi;
            }
            let s = me.lam * m + pj.w * me.mi + sc * m;
            *dp += s * gw0(xij, sqrt(r2));
        }
        return;
    }
    if (r2 < prm.h0 * prm.h0) {
        let lj = level_of(j);
        let lvj = lv_of(lj);
        let hm = max(me.hi, lvj.x);
        if (r2 < hm * hm) {
            let mj = lvj.w;
            let s = me.lam * mj + pj.w * me.mi + scorr_me(me, r2, lj, lvj) * mj;
            *dp += s * gsym(xij, sqrt(r2), me.lv, lvj);
        }
    }
}
fn delta_wall(dp: ptr<function, vec3<f32>>, me: Me, k: u32) {
    let xik = min_image_r(me.p - bpos[k].xyz, me.inv);
    let r2 = dot(xik, xik);
    let hm = max(me.hi, prm.h0);
    if (r2 < hm * hm) {
        let s = (me.lam + scorr(r2, me.lv, prm.lv[0])) * prm.lv[0].w;
        *dp += s * gsym(xik, sqrt(r2), me.lv, prm.lv[0]);
    }
}

@compute @workgroup_size(WG_PARTICLES)
fn compute_delta(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let me = me_of(i, scratch[i]);
    var dp = vec3<f32>(0.0);
    let c = cell_coord(me.p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = row_entries(me.p, c, dy, dz, grid);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j_end = cell_start[e.y];
                for (var j = cell_start[e.x]; j < j_end; j++) { delta_fluid(&dp, me, j); }
                let k_end = bcell_start[e.y];
                for (var k = bcell_start[e.x]; k < k_end; k++) { delta_wall(&dp, me, k); }
            }
        }
    }
    pred[i] = vec4<f32>(confine(me.p + dp / prm.rest_density), 0.0);
}

@compute @workgroup_size(WG_PARTICLES)
fn update_velocity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    // w: the height gained in this substep, for the adiabatic cooling of eq. 7 (thermo.wgsl)
    let d = min_image(pred[i].xyz - pos[i].xyz, grid);
    vel[i] = vec4<f32>(d * prm.inv_dt, d.y);
}

// Pair terms of the velocity passes for a candidate j with r2 < h0^2: j's level constants and
// whether r < max(h_i, h_j). All level 0: the table's first row, no level look-up.
struct Pair {
    inside: bool,
    lvj: vec4<f32>,
}
fn pair_of(r2: f32, hi: f32, j: u32) -> Pair {
    if (live.single_level != 0u) { return Pair(true, prm.lv[0]); }
    let lvj = lv_of(level_of(j));
    let hm = max(hi, lvj.x);
    return Pair(r2 < hm * hm, lvj);
}
// W and grad W of eq. 19 (level 0 alone: the same values without the per-level selects)
fn pair_w(r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> f32 {
    if (live.single_level != 0u) { return w0(r2); }
    return wsym(r2, lvi, lvj);
}
fn pair_g(xij: vec3<f32>, r2: f32, lvi: vec4<f32>, lvj: vec4<f32>) -> vec3<f32> {
    if (live.single_level != 0u) { return gw0(xij, sqrt(r2)); }
    return gsym(xij, sqrt(r2), lvi, lvj);
}

// omega_i = sum_j V_j (v_i - v_j) x grad_i W_ij, V_j = m_j / rho_j; written over pos (x is dead).
@compute @workgroup_size(WG_PARTICLES)
fn vorticity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let p = pred[i].xyz;
    let vi = vel[i].xyz;
    let lvi = lv_of(level_of(i));
    let hi = lvi.x;
    var w = vec3<f32>(0.0);
    let c = cell_coord(p, grid);
    let inv = 1.0 / grid.domain_size;
    // every radius is <= h0: pairs beyond it are rejected before their level is loaded
    let h02 = prm.h0 * prm.h0;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = row_entries(p, c, dy, dz, grid);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j_end = cell_start[e.y];
                for (var j = cell_start[e.x]; j < j_end; j++) {
                    let xij = min_image_r(p - pred[j].xyz, inv);
                    let r2 = dot(xij, xij);
                    if (r2 >= h02) { continue; }
                    let pk = pair_of(r2, hi, j);
                    if (!pk.inside) { continue; }
                    let lvj = pk.lvj;
                    let rho_j = density[j];
                    let vj = lvj.w / rho_j;
                    w += vj * cross(vi - vel[j].xyz, pair_g(xij, r2, lvi, pk.lvj));
                }
            }
        }
    }
    pos[i] = vec4<f32>(w, length(w));
}

// XSPH viscosity v_i += c sum_j 2 m_j / (rho_i + rho_j) (v_j - v_i) W_ij and vorticity confinement
// a = eps (N x omega_i), N = eta / |eta|, eta = sum_j V_j (|omega_j| - |omega_i|) grad_i W_ij;
// then the speed clamp. Writes the new velocity to scratch.
@compute @workgroup_size(WG_PARTICLES)
fn viscosity_confine(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let p = pred[i].xyz;
    let vi = vel[i].xyz;
    let lvi = lv_of(level_of(i));
    let hi = lvi.x;
    let use_vort = prm.vorticity > 0.0;
    let rho_i = density[i];
    var wi = 0.0;
    if (use_vort) { wi = pos[i].w; }
    var acc = vec3<f32>(0.0);
    var eta = vec3<f32>(0.0);
    let c = cell_coord(p, grid);
    let inv = 1.0 / grid.domain_size;
    // every radius is <= h0: pairs beyond it are rejected before their level is loaded
    let h02 = prm.h0 * prm.h0;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            let rows = row_entries(p, c, dy, dz, grid);
            for (var s = 0u; s < 2u; s++) {
                let e = select(rows.xy, rows.zw, s == 1u);
                if (e.x == e.y) { continue; }
                let j_end = cell_start[e.y];
                for (var j = cell_start[e.x]; j < j_end; j++) {
                    let xij = min_image_r(p - pred[j].xyz, inv);
                    let r2 = dot(xij, xij);
                    if (r2 >= h02) { continue; }
                    let pk = pair_of(r2, hi, j);
                    if (!pk.inside) { continue; }
                    let lvj = pk.lvj;
                    let rho_j = density[j];
                    let vj = lvj.w / rho_j;
                    // 2 m_j / (rho_i + rho_j): pairwise symmetric, so XSPH conserves momentum
                    let vs = 2.0 * lvj.w / (rho_i + rho_j);
                    acc += vs * pair_w(r2, lvi, pk.lvj) * (vel[j].xyz - vi);
                    if (use_vort) {
                        eta += vj * (pos[j].w - wi) * pair_g(xij, r2, lvi, pk.lvj);
                    }
                }
            }
        }
    }
    var v = vi + prm.xsph * acc;
    let le = length(eta);
    if (use_vort && le > 0.0) {
        v += prm.dt * prm.vorticity * cross(eta / le, pos[i].xyz);
    }
    scratch[i] = vec4<f32>(clamp_speed(v), vel[i].w);
}
