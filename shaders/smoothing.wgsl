// Temperature smoothing as a constraint (paper section 4.1, eqs. 12-17), one Jacobi iteration:
// reads thermo_in, writes thermo_out (only .x changes), so the result does not depend on the
// order in which particles run. f64 mirror: src/sim/reference/smoothing.rs (`smooth_temperature`).
//
// With a_ij = V_j (x_ij . gradW_ij) / (|x_ij|^2 + eps)  (<= 0; V_j = volume0 2^-l_j, the m_j/rho0
// of eq. 13; symmetric spiky gradient of eq. 19):
//   C_i = sum_j a_ij (T_i - T_j)                    (eq. 13, the SPH Laplacian)
//   dC_i/dT_i = S_i = sum_j a_ij, dC_i/dT_k = -a_ik (eq. 16)
//   lambda_i = -C_i / (S_i^2 + sum_k a_ik^2)        (eq. 17a)
//   T*_i = T_i + kappa lambda_i S_i                 (eq. 17b)
// Conservative form (S.conservative = 1, physics.smoothing.conservative): eq. 17b written as
// pair fluxes of the dry static temperature s = T + Gamma_d y (S.lapse = Gamma_d),
// T*_i = T_i - sum_j (k_i + k_j) / 2 a_ij (s_i - s_j) with k_i = kappa S_i / (S_i^2 +
// sum_k a_ik^2) from the entry `smooth_factor` (run first). The paper's step is
// T_i - k_i C_i; with k symmetrised per pair, m_i a_ij (s_i - s_j) (k_i + k_j) / 2 is
// antisymmetric in i and j, so sum_i m_i T_i is kept exactly: the smoothing moves heat, it
// creates or destroys none (the paper's per-particle projection does not, docs/PHYSICS.md
// "Heat budget"). In f32 it is kept on average: T_i takes its flux with `add_unbiased`
// (shared/common.wgsl), as a flux below half an ulp would otherwise be dropped. Mixing evens
// out s, not T: a well-mixed layer has one potential temperature and T falling at Gamma_d,
// which smoothing T would turn stable.
// Walls: insulated (S.fixed_walls = 0: the boundary particles are left out, no heat crosses the
// floor or the ceiling) or fixed-temperature (neighbours with their own temperature boundary.w,
// level 0). kappa is the per-iteration share of the configured rate (SmoothParams::new).
//
// Vapor mixing (entrainment, docs/PHYSICS.md "Vapor mixing") rides on the same neighbour loop:
//   v*_i = v_i + vapor_rate sum_j e_ij min(l_i, l_j) a_ij (v_i - v_j)
// (vapor_rate = 2 D dt / iterations): an explicit step of dv/dt = D lap v over the fluid pairs of
// which at least one holds cloud water (e_ij = 1; clear air, and the stable inversion over it,
// does not diffuse), or over every fluid pair with S.mix_everywhere; no vapor crosses a wall.
// m_i e_ij a_ij = e_ij m_i V_j g_ij / (r^2 + eps) is
// symmetric in i and j, so the pair terms cancel in sum_i m_i v_i: mixing moves vapor, it
// creates none. The limiter l_i = min(1, 0.5 / (vapor_rate sum_j e_ij |a_ij|)) of the entry
// `vapor_limit` (run first) keeps every step convex however close particles come (a_ij grows
// as 1 / r): no vapor goes negative or overshoots, and the pair weights stay symmetric.
//!include shared/common.wgsl

struct SmoothParams {
    // Gamma_d of the conservative form (0 otherwise)
    lapse: f32,
    h0: f32,
    kappa: f32,
    epsilon: f32,
    volume0: f32,
    fixed_walls: u32,
    vapor_rate: f32,
    // 1: the conservative (pair-flux) form of eq. 17b
    conservative: u32,
    // 1: vapor mixes between every pair of fluid neighbours (e_ij = 1); 0: at cloud edges
    mix_everywhere: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> S: SmoothParams;
@group(0) @binding(2) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> info: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read> thermo_in: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> thermo_out: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> cell_start: array<u32>;
@group(0) @binding(7) var<storage, read> bpos: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read> bcell_start: array<u32>;
// the vapor-mixing limiter l_i (written by vapor_limit, read by smooth_temperature)
@group(0) @binding(9) var<storage, read_write> vapor_limit_of: array<f32>;
@group(0) @binding(10) var<storage, read> live: Live;
// k_i = kappa S_i / (S_i^2 + sum a^2) of the conservative form (written by smooth_factor)
@group(0) @binding(11) var<storage, read_write> smooth_factor_of: array<f32>;

fn radius_of_level(level: u32) -> f32 {
    return S.h0 * exp2(-f32(level) / 3.0);
}

// A level's (h, spiky factor, volume), and what the pair loops need of the uniforms, computed once
// per invocation by the same expressions (so the same values); the pair loops select a
// neighbour's row instead of computing three exp2 and reading the uniforms for every pair
// (docs/PERFORMANCE.md "PBF / Session 12").
struct Pc {
    // level l: (radius_of_level(l), spiky_factor(f0, l), volume0 2^-l)
    lv: array<vec3<f32>, MAX_LEVEL + 1u>,
    h02: f32,
    eps: f32,
    image: Image,
}
fn pair_consts() -> Pc {
    let f0 = spiky_factor0();
    var lv: array<vec3<f32>, MAX_LEVEL + 1u>;
    for (var l = 0u; l < MAX_LEVEL + 1u; l++) {
        lv[l] = vec3<f32>(radius_of_level(l), spiky_factor(f0, l), S.volume0 * exp2(-f32(l)));
    }
    return Pc(lv, S.h0 * S.h0, S.epsilon, image_of(grid));
}
// Row l of the table by selects (a per-lane indexed read is a scalar loop on SIMD CPUs).
fn level_row(pc: Pc, l: u32) -> vec3<f32> {
    var v = pc.lv[0];
    v = select(v, pc.lv[1], l == 1u);
    v = select(v, pc.lv[2], l == 2u);
    v = select(v, pc.lv[3], l == 3u);
    v = select(v, pc.lv[4], l == 4u);
    v = select(v, pc.lv[5], l == 5u);
    v = select(v, pc.lv[6], l == 6u);
    return select(v, pc.lv[MAX_LEVEL], l >= MAX_LEVEL);
}
// Spiky gradient factor -45 / (pi h^6) of level 0 (once per particle, not per pair).
fn spiky_factor0() -> f32 {
    return -45.0 / (PI * pow(S.h0, 6.0));
}
// ... and of level l from it: h = h0 2^(-l/3), so (h0 / h)^6 = 4^l.
fn spiky_factor(f0: f32, level: u32) -> f32 {
    return f0 * exp2(2.0 * f32(level));
}

// One side of x_ij . gradW_ij: f (h - r)^2 r for r < h (spiky_grad's factor (h - r)^2 / r x_ij,
// dotted with x_ij), 0 at r = 0 as spiky_grad.
fn radial_spiky(r: f32, h: f32, f: f32) -> f32 {
    let d = h - r;
    return select(f * d * d * r, 0.0, r >= h || r <= 1e-9 * h);
}

// Coefficient a_ij = V_j (x_ij . gradW_ij) / (r^2 + eps) with eq. 19's symmetric gradient; 0
// outside both kernel radii. (h, spiky factor) of i and j are passed in: no pow per pair.
fn laplacian_coefficient(r2: f32, hi: f32, fi: f32, hj: f32, fj: f32, volume: f32, eps: f32) -> f32 {
    let r = sqrt(r2);
    let g = 0.5 * (radial_spiky(r, hi, fi) + radial_spiky(r, hj, fj));
    return volume * g / (r2 + eps);
}

// sum_j e_ij |a_ij| of particle i over its fluid neighbours (the vapor-mixing pairs).
struct Dm {
    i: u32,
    p: vec3<f32>,
    hi: f32,
    fi: f32,
    // i mixes with every neighbour: it holds cloud water, or S.mix_everywhere
    mixes_all: bool,
    pc: Pc,
}
fn demand_pair(sum: ptr<function, f32>, me: Dm, j: u32) {
    let pc = me.pc;
    let xij = min_image_by_reciprocal(me.p - pos[j].xyz, pc.image);
    let r2 = dot(xij, xij);
    if (j == me.i || r2 >= pc.h02 || !(me.mixes_all || thermo_in[j].z > 0.0)) { return; }
    let lvj = level_row(pc, info[j].y);
    let hm = max(me.hi, lvj.x);
    if (r2 >= hm * hm) { return; }
    *sum += abs(laplacian_coefficient(r2, me.hi, me.fi, lvj.x, lvj.y, lvj.z, pc.eps));
}
//!walk demand_scan
fn vapor_demand(i: u32) -> f32 {
    let xi = pos[i].xyz;
    let pc = pair_consts();
    let lvi = level_row(pc, info[i].y);
    let me = Dm(i, xi, lvi.x, lvi.y, S.mix_everywhere != 0u || thermo_in[i].z > 0.0, pc);
    var sum = 0.0;
    demand_scan(&sum, me);
    return sum;
}

@compute @workgroup_size(WG_PARTICLES)
fn vapor_limit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let demand = S.vapor_rate * vapor_demand(i);
    vapor_limit_of[i] = select(1.0, min(1.0, 0.5 / demand), demand > 0.0);
}

// The particle a smoothing pass is about, and its sums: sum_j a_ij, sum_j a_ij^2, the
// constraint sum_j a_ij (T_i - T_j), and the vapor mixing sum_j e_ij a_ij (v_i - v_j).
struct Sm {
    i: u32,
    p: vec3<f32>,
    hi: f32,
    fi: f32,
    ti: f32,
    vi: f32,
    // i mixes with every neighbour: it holds cloud water, or S.mix_everywhere
    mixes_all: bool,
    mixing: bool,
    limit: f32,
    // k_i of the conservative form (0 otherwise)
    ki: f32,
    pc: Pc,
}
struct SmAcc {
    sum_a: f32,
    sum_a2: f32,
    c: f32,
    cv: f32,
    // sum_j (k_i + k_j) / 2 a_ij (T_i - T_j) of the conservative form
    flux: f32,
}
fn smooth_pair(a: ptr<function, SmAcc>, me: Sm, j: u32) {
    let pc = me.pc;
    let xij = min_image_by_reciprocal(me.p - pos[j].xyz, pc.image);
    let r2 = dot(xij, xij);
    // every radius is <= h0: farther pairs are rejected before the level load
    if (j == me.i || r2 >= pc.h02) { return; }
    let lvj = level_row(pc, info[j].y);
    let hm = max(me.hi, lvj.x);
    if (r2 >= hm * hm) { return; }
    let aij = laplacian_coefficient(r2, me.hi, me.fi, lvj.x, lvj.y, lvj.z, pc.eps);
    (*a).sum_a += aij;
    (*a).sum_a2 += aij * aij;
    let tj = thermo_in[j];
    (*a).c += aij * (me.ti - tj.x);
    if (S.conservative != 0u) {
        let ds = me.ti - tj.x + S.lapse * xij.y;
        (*a).flux += 0.5 * (me.ki + smooth_factor_of[j]) * aij * ds;
    }
    if (me.mixing && (me.mixes_all || tj.z > 0.0)) {
        (*a).cv += min(me.limit, vapor_limit_of[j]) * aij * (me.vi - tj.y);
    }
}
fn smooth_wall(a: ptr<function, SmAcc>, me: Sm, k: u32) {
    let pc = me.pc;
    let b = bpos[k];
    let xik = min_image_by_reciprocal(me.p - b.xyz, pc.image);
    let r2 = dot(xik, xik);
    if (r2 >= pc.h02) { return; }
    // wall particles continue the level-0 lattice
    let aik = laplacian_coefficient(r2, me.hi, me.fi, pc.lv[0].x, pc.lv[0].y, pc.lv[0].z, pc.eps);
    (*a).sum_a += aik;
    (*a).sum_a2 += aik * aik;
    (*a).c += aik * (me.ti - b.w);
    // a wall at a fixed temperature exchanges heat with the particle alone
    (*a).flux += me.ki * aik * (me.ti - b.w + S.lapse * xik.y);
}
//!walk smooth_scan

// The sums of particle i's smoothing pass (`ki`: its k of the conservative form, or 0).
fn smooth_sums(i: u32, ki: f32) -> SmAcc {
    let th = thermo_in[i];
    let pc = pair_consts();
    let lvi = level_row(pc, info[i].y);
    let mixing = S.vapor_rate > 0.0;
    var limit_i = 1.0;
    if (mixing) { limit_i = vapor_limit_of[i]; }
    let me = Sm(i, pos[i].xyz, lvi.x, lvi.y, th.x, th.y, S.mix_everywhere != 0u || th.z > 0.0, mixing, limit_i, ki, pc);
    var acc = SmAcc(0.0, 0.0, 0.0, 0.0, 0.0);
    smooth_scan(&acc, me);
    return acc;
}

// k_i = kappa S_i / (S_i^2 + sum_k a_ik^2) of the conservative form (eq. 17b's step per unit
// of C_i), 0 without neighbours.
@compute @workgroup_size(WG_PARTICLES)
fn smooth_factor(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let acc = smooth_sums(i, 0.0);
    let g = acc.sum_a * acc.sum_a + acc.sum_a2;
    smooth_factor_of[i] = select(0.0, S.kappa * acc.sum_a / g, g > 0.0);
}

@compute @workgroup_size(WG_PARTICLES)
fn smooth_temperature(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let th = thermo_in[i];
    var ki = 0.0;
    if (S.conservative != 0u) { ki = smooth_factor_of[i]; }
    let acc = smooth_sums(i, ki);
    let sum_a = acc.sum_a;
    let sum_a2 = acc.sum_a2;
    let c = acc.c;
    let cv = acc.cv;
    let ti = th.x;
    let vi = th.y;
    var out = th;
    let g = sum_a * sum_a + sum_a2;
    if (S.conservative != 0u) {
        // The flux of a substep is often below half an ulp of T where s is nearly even: a
        // plain sum drops it, and the drops do not cancel (a warm particle's large loss is kept,
        // the small gains of its neighbours are not; docs/PHYSICS.md "Heat budget"). Keyed on
        // the flux too: the iterations of a substep see the same position, and a key that did
        // not change with them would round a steady small gain the same way every time.
        let salt = pcg_hash(bitcast<u32>(ti) ^ pcg_hash(bitcast<u32>(acc.flux)));
        let key = state_key(pos[i].xyz, salt);
        out.x = add_unbiased(ti, -acc.flux, key);
    } else if (g > 0.0) {
        // T* = T + kappa lambda S with lambda = -C / g.
        out.x = ti - S.kappa * c * sum_a / g;
    }
    out.y = vi + S.vapor_rate * cv;
    thermo_out[i] = out;
}
