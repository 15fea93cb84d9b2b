// Position Based Fluids (Macklin & Mueller 2013) per substep, with per-particle radii and masses
// (level l: h = h0 2^(-l/3), m = m0 2^(-l)) through the symmetric kernels of eq. 19, and the
// floor/ceiling boundary particles counting in the density with the fluid particle's mass (eq. 18).
// Entry points, in order: predict, then per iteration compute_lambda + compute_delta (+ copy), then
// update_velocity, vorticity (when enabled), viscosity_confine (+ copy).
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
    _p0: f32,
    _p1: f32,
    _p2: f32,
    // per level l: (h_l, poly6 factor 315/(64 pi h^9), spiky factor -45/(pi h^6), m_l): no pow or
    // exp2 per neighbour pair (the dominant cost on CPU Vulkan)
    lv: array<vec4<f32>, 8>,
}

@group(0) @binding(0) var<uniform> grid: GridParams;
@group(0) @binding(1) var<uniform> prm: PbfParams;
// positions x at the start of the substep; vorticity omega (xyz, |omega|) after update_velocity
@group(0) @binding(2) var<storage, read_write> pos: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> vel: array<vec4<f32>>;
// predicted positions p*
@group(0) @binding(4) var<storage, read_write> pred: array<vec4<f32>>;
// output of compute_delta (new p*) and viscosity_confine (new v)
@group(0) @binding(5) var<storage, read_write> scratch: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> lambda: array<f32>;
@group(0) @binding(7) var<storage, read_write> density: array<f32>;
@group(0) @binding(8) var<storage, read_write> info: array<vec2<u32>>;
@group(0) @binding(9) var<storage, read_write> cell_start: array<u32>;
// boundary particles: xyz, w = temperature; cell-ordered with their own table
@group(0) @binding(10) var<storage, read_write> bpos: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> bcell_start: array<u32>;

fn linear_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.y * nwg.x * 64u + gid.x;
}

fn level_of(i: u32) -> u32 {
    return min(info[i].y, 7u);
}
fn radius_of(i: u32) -> f32 {
    return prm.lv[level_of(i)].x;
}
fn mass_of(i: u32) -> f32 {
    return prm.lv[level_of(i)].w;
}
// poly6 and spiky gradient of level l from the table (same values as common.wgsl's poly6/spiky_grad)
fn w_l(r2: f32, l: u32) -> f32 {
    let h = prm.lv[l].x;
    let d = h * h - r2;
    if (d <= 0.0) { return 0.0; }
    return prm.lv[l].y * d * d * d;
}
fn gw_l(xij: vec3<f32>, r: f32, l: u32) -> vec3<f32> {
    let h = prm.lv[l].x;
    if (r >= h || r <= 1e-9 * h) { return vec3<f32>(0.0); }
    let d = h - r;
    return (prm.lv[l].z * d * d / r) * xij;
}
// eq. 19 by level
fn wsym(r2: f32, li: u32, lj: u32) -> f32 {
    if (li == lj) { return w_l(r2, li); }
    return 0.5 * (w_l(r2, li) + w_l(r2, lj));
}
fn gsym(xij: vec3<f32>, r: f32, li: u32, lj: u32) -> vec3<f32> {
    if (li == lj) { return gw_l(xij, r, li); }
    return 0.5 * (gw_l(xij, r, li) + gw_l(xij, r, lj));
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

@compute @workgroup_size(64)
fn predict(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= grid.n_particles) { return; }
    var v = vel[i].xyz;
    v.y = v.y - prm.gravity * prm.dt;
    v = clamp_speed(v);
    pred[i] = vec4<f32>(confine(pos[i].xyz + v * prm.dt), 0.0);
}

// Artificial pressure s_corr = -k (W / W(dq h))^n h_i h_j (k dimensionless; h_i h_j gives lambda's
// units, m^2, so the term is scale free).
fn scorr(r2: f32, li: u32, lj: u32) -> f32 {
    if (prm.scorr_k == 0.0) { return 0.0; }
    let hi = prm.lv[li].x;
    let hj = prm.lv[lj].x;
    let hb = prm.scorr_dq * 0.5 * (hi + hj);
    let x = wsym(r2, li, lj) / wsym(hb * hb, li, lj);
    var t = 1.0;
    for (var k = 0u; k < u32(prm.scorr_n); k++) { t = t * x; }
    return -prm.scorr_k * t * hi * hj;
}

@compute @workgroup_size(64)
fn compute_lambda(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= grid.n_particles) { return; }
    let p = pred[i].xyz;
    let li = level_of(i);
    let hi = radius_of(i);
    let mi = mass_of(i);
    let inv_rho0 = 1.0 / prm.rest_density;
    var rho = 0.0;
    var grad_i = vec3<f32>(0.0);
    var sum_grad2 = 0.0;
    let c = cell_coord(p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                let j_end = cell_start[n + 1];
                for (var j = cell_start[n]; j < j_end; j++) {
                    let xij = min_image(p - pred[j].xyz, grid);
                    let r2 = dot(xij, xij);
                    let lj = level_of(j);
                    let hj = radius_of(j);
                    let hm = max(hi, hj);
                    if (r2 >= hm * hm) { continue; }
                    let mj = mass_of(j);
                    rho += mj * wsym(r2, li, lj);
                    let g = gsym(xij, sqrt(r2), li, lj) * (mj * inv_rho0);
                    grad_i += g;
                    sum_grad2 += dot(g, g);
                }
                let k_end = bcell_start[n + 1];
                for (var k = bcell_start[n]; k < k_end; k++) {
                    let xik = min_image(p - bpos[k].xyz, grid);
                    let r2 = dot(xik, xik);
                    let hm = max(hi, prm.h0);
                    if (r2 >= hm * hm) { continue; }
                    rho += mi * wsym(r2, li, 0u);
                    grad_i += gsym(xik, sqrt(r2), li, 0u) * (mi * inv_rho0);
                }
            }
        }
    }
    let constraint = rho * inv_rho0 - 1.0;
    lambda[i] = -constraint / (sum_grad2 + dot(grad_i, grad_i) + prm.eps);
    density[i] = rho;
}

@compute @workgroup_size(64)
fn compute_delta(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= grid.n_particles) { return; }
    let p = pred[i].xyz;
    let li = level_of(i);
    let hi = radius_of(i);
    let mi = mass_of(i);
    let lam_i = lambda[i];
    var dp = vec3<f32>(0.0);
    let c = cell_coord(p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                let j_end = cell_start[n + 1];
                for (var j = cell_start[n]; j < j_end; j++) {
                    let xij = min_image(p - pred[j].xyz, grid);
                    let r2 = dot(xij, xij);
                    let lj = level_of(j);
                    let hj = radius_of(j);
                    let hm = max(hi, hj);
                    if (r2 >= hm * hm) { continue; }
                    let mj = mass_of(j);
                    let s = lam_i * mj + lambda[j] * mi + scorr(r2, li, lj) * mj;
                    dp += s * gsym(xij, sqrt(r2), li, lj);
                }
                let k_end = bcell_start[n + 1];
                for (var k = bcell_start[n]; k < k_end; k++) {
                    let xik = min_image(p - bpos[k].xyz, grid);
                    let r2 = dot(xik, xik);
                    let hm = max(hi, prm.h0);
                    if (r2 >= hm * hm) { continue; }
                    let s = (lam_i + scorr(r2, li, 0u)) * mi;
                    dp += s * gsym(xik, sqrt(r2), li, 0u);
                }
            }
        }
    }
    scratch[i] = vec4<f32>(confine(p + dp / prm.rest_density), 0.0);
}

@compute @workgroup_size(64)
fn update_velocity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= grid.n_particles) { return; }
    vel[i] = vec4<f32>(min_image(pred[i].xyz - pos[i].xyz, grid) * prm.inv_dt, 0.0);
}

// omega_i = sum_j V_j (v_i - v_j) x grad_i W_ij, V_j = m_j / rho_j; written over pos (x is dead).
@compute @workgroup_size(64)
fn vorticity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= grid.n_particles) { return; }
    let p = pred[i].xyz;
    let vi = vel[i].xyz;
    let li = level_of(i);
    let hi = radius_of(i);
    var w = vec3<f32>(0.0);
    let c = cell_coord(p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                let j_end = cell_start[n + 1];
                for (var j = cell_start[n]; j < j_end; j++) {
                    let xij = min_image(p - pred[j].xyz, grid);
                    let r2 = dot(xij, xij);
                    let lj = level_of(j);
                    let hj = radius_of(j);
                    let hm = max(hi, hj);
                    if (r2 >= hm * hm) { continue; }
                    let vj = mass_of(j) / density[j];
                    w += vj * cross(vi - vel[j].xyz, gsym(xij, sqrt(r2), li, lj));
                }
            }
        }
    }
    pos[i] = vec4<f32>(w, length(w));
}

// XSPH viscosity v_i += c sum_j 2 m_j / (rho_i + rho_j) (v_j - v_i) W_ij and vorticity confinement
// a = eps (N x omega_i), N = eta / |eta|, eta = sum_j V_j (|omega_j| - |omega_i|) grad_i W_ij;
// then the speed clamp. Writes the new velocity to scratch.
@compute @workgroup_size(64)
fn viscosity_confine(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= grid.n_particles) { return; }
    let p = pred[i].xyz;
    let vi = vel[i].xyz;
    let li = level_of(i);
    let hi = radius_of(i);
    let use_vort = prm.vorticity > 0.0;
    let rho_i = density[i];
    var wi = 0.0;
    if (use_vort) { wi = pos[i].w; }
    var acc = vec3<f32>(0.0);
    var eta = vec3<f32>(0.0);
    let c = cell_coord(p, grid);
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let n = neighbor_cell(c, vec3<i32>(dx, dy, dz), grid);
                if (n < 0) { continue; }
                let j_end = cell_start[n + 1];
                for (var j = cell_start[n]; j < j_end; j++) {
                    let xij = min_image(p - pred[j].xyz, grid);
                    let r2 = dot(xij, xij);
                    let lj = level_of(j);
                    let hj = radius_of(j);
                    let hm = max(hi, hj);
                    if (r2 >= hm * hm) { continue; }
                    let vj = mass_of(j) / density[j];
                    // 2 m_j / (rho_i + rho_j): pairwise symmetric, so XSPH conserves momentum
                    let vs = 2.0 * mass_of(j) / (rho_i + density[j]);
                    acc += vs * wsym(r2, li, lj) * (vel[j].xyz - vi);
                    if (use_vort) {
                        eta += vj * (pos[j].w - wi) * gsym(xij, sqrt(r2), li, lj);
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
    scratch[i] = vec4<f32>(clamp_speed(v), 0.0);
}
