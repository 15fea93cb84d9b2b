//! f64 mirror of shaders/pbf.wgsl, same entry names. Inputs are cell-ordered arrays with their
//! cell table (as after the grid build); each function returns what its shader writes.
use super::grid::for_each_neighbor;
use super::kernels::{min_image, poly6_sym, spiky_grad_sym};
use crate::sim::grid_params::GridParams;
use crate::sim::pbf::PbfParams;

type V3 = [f64; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn len(a: V3) -> f64 {
    dot(a, a).sqrt()
}

/// Shared inputs of the neighbour loops.
pub struct Scene<'a> {
    pub grid: &'a GridParams,
    pub prm: &'a PbfParams,
    pub cell_start: &'a [u32],
    pub level: &'a [u32],
    /// boundary particles (cell-ordered) and their table
    pub bpos: &'a [V3],
    pub bcell_start: &'a [u32],
}

impl Scene<'_> {
    fn h(&self, i: usize) -> f64 {
        self.prm.h0 as f64 * (-(self.level[i] as f64) / 3.0).exp2()
    }
    fn m(&self, i: usize) -> f64 {
        self.prm.m0 as f64 * (-(self.level[i] as f64)).exp2()
    }
    fn scorr(&self, r2: f64, hi: f64, hj: f64) -> f64 {
        let k = self.prm.scorr_k as f64;
        if k == 0.0 {
            return 0.0;
        }
        let hb = self.prm.scorr_dq as f64 * 0.5 * (hi + hj);
        let wdq = poly6_sym(hb * hb, hi, hj);
        -k * (poly6_sym(r2, hi, hj) / wdq).powf(self.prm.scorr_n as f64) * hi * hj
    }
}

/// Periodic wrap in x/z and the walls in y (mirror of `confine`).
pub fn confine(grid: &GridParams, p: V3) -> V3 {
    let s = grid.domain_size.map(|v| v as f64);
    let mut q = p;
    for (a, per) in [(0, grid.periodic_x()), (2, grid.periodic_z())] {
        if per {
            q[a] -= s[a] * (q[a] / s[a]).floor();
            if q[a] >= s[a] {
                q[a] = 0.0;
            }
        } else {
            q[a] = q[a].clamp(0.0, s[a]);
        }
    }
    q[1] = q[1].clamp(0.0, s[1]);
    q
}

fn clamp_speed(prm: &PbfParams, v: V3) -> V3 {
    let s = len(v);
    let m = prm.max_speed as f64;
    if s > m {
        scale(v, m / s)
    } else {
        v
    }
}

pub fn predict(grid: &GridParams, prm: &PbfParams, pos: &[V3], vel: &[V3]) -> Vec<V3> {
    let dt = prm.dt as f64;
    pos.iter()
        .zip(vel)
        .map(|(p, v)| {
            let mut v = *v;
            v[1] -= prm.gravity as f64 * dt;
            let v = clamp_speed(prm, v);
            confine(grid, add(*p, scale(v, dt)))
        })
        .collect()
}

/// Returns (lambda, density).
pub fn compute_lambda(sc: &Scene, pred: &[V3]) -> (Vec<f64>, Vec<f64>) {
    let rho0 = sc.prm.rest_density as f64;
    let h0 = sc.prm.h0 as f64;
    let mut lam = Vec::with_capacity(pred.len());
    let mut den = Vec::with_capacity(pred.len());
    for (i, &p) in pred.iter().enumerate() {
        let hi = sc.h(i);
        let m0 = sc.prm.m0 as f64;
        let mut rho = 0.0;
        let mut grad_i = [0.0; 3];
        let mut sum2 = 0.0;
        let mut near_wall = false;
        for_each_neighbor(sc.grid, sc.cell_start, pred, p, |j, xij| {
            let r2 = dot(xij, xij);
            let hj = sc.h(j);
            if r2 >= hi.max(hj).powi(2) {
                return;
            }
            let mj = sc.m(j);
            rho += mj * poly6_sym(r2, hi, hj);
            let g = scale(spiky_grad_sym(xij, r2.sqrt(), hi, hj), mj / rho0);
            grad_i = add(grad_i, g);
            sum2 += dot(g, g);
        });
        for_each_neighbor(sc.grid, sc.bcell_start, sc.bpos, p, |_, xik| {
            let r2 = dot(xik, xik);
            if r2 >= hi.max(h0).powi(2) {
                return;
            }
            // wall particles weigh m0 whatever the fluid particle's level
            rho += m0 * poly6_sym(r2, hi, h0);
            near_wall = true;
            grad_i = add(
                grad_i,
                scale(spiky_grad_sym(xik, r2.sqrt(), hi, h0), m0 / rho0),
            );
        });
        let mut c = rho / rho0 - 1.0;
        // the under-density tolerance, and a share of the rest for split particles, none next
        // to a wall (the shader)
        if c < 0.0 {
            c = (c + sc.prm.expansion_tolerance as f64).min(0.0);
            if sc.level[i] > 0 {
                c *= if near_wall {
                    0.0
                } else {
                    sc.prm.split_expansion_weight as f64
                };
            }
        }
        lam.push(-c / (sum2 + dot(grad_i, grad_i) + sc.prm.eps as f64));
        den.push(rho);
    }
    (lam, den)
}

/// Returns the corrected predicted positions p* + delta p (confined).
pub fn compute_delta(sc: &Scene, pred: &[V3], lambda: &[f64]) -> Vec<V3> {
    let rho0 = sc.prm.rest_density as f64;
    let h0 = sc.prm.h0 as f64;
    pred.iter()
        .enumerate()
        .map(|(i, &p)| {
            let (hi, mi, li) = (sc.h(i), sc.m(i), lambda[i]);
            let mut dp = [0.0; 3];
            for_each_neighbor(sc.grid, sc.cell_start, pred, p, |j, xij| {
                let r2 = dot(xij, xij);
                let hj = sc.h(j);
                if r2 >= hi.max(hj).powi(2) {
                    return;
                }
                let mj = sc.m(j);
                let s = li * mj + lambda[j] * mi + sc.scorr(r2, hi, hj) * mj;
                dp = add(dp, scale(spiky_grad_sym(xij, r2.sqrt(), hi, hj), s));
            });
            for_each_neighbor(sc.grid, sc.bcell_start, sc.bpos, p, |_, xik| {
                let r2 = dot(xik, xik);
                if r2 >= hi.max(h0).powi(2) {
                    return;
                }
                let s = (li + sc.scorr(r2, hi, h0)) * sc.prm.m0 as f64;
                dp = add(dp, scale(spiky_grad_sym(xik, r2.sqrt(), hi, h0), s));
            });
            confine(sc.grid, add(p, scale(dp, 1.0 / rho0)))
        })
        .collect()
}

pub fn update_velocity(grid: &GridParams, prm: &PbfParams, pos: &[V3], pred: &[V3]) -> Vec<V3> {
    let size = grid.domain_size.map(|v| v as f64);
    let per = [grid.periodic_x(), grid.periodic_z()];
    pos.iter()
        .zip(pred)
        .map(|(x, p)| scale(min_image(sub(*p, *x), size, per), prm.inv_dt as f64))
        .collect()
}

/// Returns (omega, |omega|) per particle.
pub fn vorticity(sc: &Scene, pred: &[V3], vel: &[V3], density: &[f64]) -> Vec<[f64; 4]> {
    pred.iter()
        .enumerate()
        .map(|(i, &p)| {
            let hi = sc.h(i);
            let mut w = [0.0; 3];
            for_each_neighbor(sc.grid, sc.cell_start, pred, p, |j, xij| {
                let r2 = dot(xij, xij);
                let hj = sc.h(j);
                if r2 >= hi.max(hj).powi(2) {
                    return;
                }
                let vj = sc.m(j) / density[j];
                let g = spiky_grad_sym(xij, r2.sqrt(), hi, hj);
                w = add(w, scale(cross(sub(vel[i], vel[j]), g), vj));
            });
            [w[0], w[1], w[2], len(w)]
        })
        .collect()
}

/// XSPH + vorticity confinement + speed clamp; `omega` is ignored when vorticity is 0.
pub fn viscosity_confine(
    sc: &Scene,
    pred: &[V3],
    vel: &[V3],
    density: &[f64],
    omega: &[[f64; 4]],
) -> Vec<V3> {
    let use_vort = sc.prm.vorticity > 0.0;
    pred.iter()
        .enumerate()
        .map(|(i, &p)| {
            let hi = sc.h(i);
            let wi = if use_vort { omega[i][3] } else { 0.0 };
            let mut acc = [0.0; 3];
            let mut eta = [0.0; 3];
            for_each_neighbor(sc.grid, sc.cell_start, pred, p, |j, xij| {
                let r2 = dot(xij, xij);
                let hj = sc.h(j);
                if r2 >= hi.max(hj).powi(2) {
                    return;
                }
                let vj = sc.m(j) / density[j];
                let vs = 2.0 * sc.m(j) / (density[i] + density[j]);
                acc = add(acc, scale(sub(vel[j], vel[i]), vs * poly6_sym(r2, hi, hj)));
                if use_vort {
                    let g = spiky_grad_sym(xij, r2.sqrt(), hi, hj);
                    eta = add(eta, scale(g, vj * (omega[j][3] - wi)));
                }
            });
            let mut v = add(vel[i], scale(acc, sc.prm.xsph as f64));
            let le = len(eta);
            if use_vort && le > 0.0 {
                let o = [omega[i][0], omega[i][1], omega[i][2]];
                let a = cross(scale(eta, 1.0 / le), o);
                v = add(v, scale(a, sc.prm.dt as f64 * sc.prm.vorticity as f64));
            }
            clamp_speed(sc.prm, v)
        })
        .collect()
}
