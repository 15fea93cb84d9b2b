//! f64 mirror of shaders/pbf.wgsl, same entry names. Inputs are cell-ordered arrays with their
//! cell table (as after the grid build); each function returns what its shader writes.
use super::common::{domain_size, min_image, poly6_sym, spiky_grad_sym};
use super::grid::{for_each_neighbor, for_each_wall_neighbor};
use crate::sim::grid_params::GridParams;
use crate::sim::pbf::PbfParams;
use glam::DVec3;

/// One element of a particle array (cell order, as on the GPU).
type V3 = [f64; 3];

/// Shared inputs of the neighbour loops.
pub struct Scene<'a> {
    pub grid: &'a GridParams,
    pub prm: &'a PbfParams,
    pub cell_start: &'a [u32],
    pub level: &'a [u32],
    /// boundary particles (cell-ordered) and their table
    pub bpos: &'a [V3],
    /// The wall particles' table (`build_wall_table`: the first and last y rows only).
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
pub fn confine(grid: &GridParams, p: DVec3) -> DVec3 {
    let s = domain_size(grid);
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

fn clamp_speed(prm: &PbfParams, v: DVec3) -> DVec3 {
    let s = v.length();
    let m = prm.max_speed as f64;
    if s > m {
        v * (m / s)
    } else {
        v
    }
}

pub fn predict(grid: &GridParams, prm: &PbfParams, pos: &[V3], vel: &[V3]) -> Vec<V3> {
    let dt = prm.dt as f64;
    pos.iter()
        .zip(vel)
        .map(|(&p, &v)| {
            let mut v = DVec3::from(v);
            v.y -= prm.gravity as f64 * dt;
            let v = clamp_speed(prm, v);
            confine(grid, DVec3::from(p) + v * dt).to_array()
        })
        .collect()
}

/// The fluid neighbours of each particle (closer than h0 at `pred`): the set the first
/// compute_lambda of a substep records in its mask and the later passes of the substep visit
/// (shaders/pbf.wgsl "Neighbour mask"; pairs that come closer later are not added).
pub fn neighbour_sets(sc: &Scene, pred: &[V3]) -> Vec<Vec<usize>> {
    let h2 = (sc.prm.h0 as f64).powi(2);
    pred.iter()
        .map(|&p| {
            let mut set = Vec::new();
            for_each_neighbor(sc.grid, sc.cell_start, pred, p, |j, xij| {
                if xij.dot(xij) < h2 {
                    set.push(j);
                }
            });
            set
        })
        .collect()
}

/// Calls `f(j, x_ij)` for the fluid pairs of particle i: the 27 cells' particles, or i's set.
fn fluid_pairs(
    sc: &Scene,
    pred: &[V3],
    sets: Option<&[Vec<usize>]>,
    i: usize,
    mut f: impl FnMut(usize, DVec3),
) {
    let Some(sets) = sets else {
        return for_each_neighbor(sc.grid, sc.cell_start, pred, pred[i], f);
    };
    let size = domain_size(sc.grid);
    let per = [sc.grid.periodic_x(), sc.grid.periodic_z()];
    for &j in &sets[i] {
        f(
            j,
            min_image(DVec3::from(pred[i]) - DVec3::from(pred[j]), size, per),
        );
    }
}

/// Returns (lambda, density).
pub fn compute_lambda(sc: &Scene, pred: &[V3]) -> (Vec<f64>, Vec<f64>) {
    compute_lambda_in(sc, pred, None)
}

/// compute_lambda over fixed neighbour sets (`compute_lambda_masked`; None: all pairs).
pub fn compute_lambda_in(
    sc: &Scene,
    pred: &[V3],
    sets: Option<&[Vec<usize>]>,
) -> (Vec<f64>, Vec<f64>) {
    let rho0 = sc.prm.rest_density as f64;
    let h0 = sc.prm.h0 as f64;
    let mut lam = Vec::with_capacity(pred.len());
    let mut den = Vec::with_capacity(pred.len());
    for (i, &p) in pred.iter().enumerate() {
        let hi = sc.h(i);
        let m0 = sc.prm.m0 as f64;
        let mut rho = 0.0;
        let mut grad_i = DVec3::ZERO;
        let mut sum2 = 0.0;
        let mut near_wall = false;
        fluid_pairs(sc, pred, sets, i, |j, xij| {
            let r2 = xij.dot(xij);
            let hj = sc.h(j);
            if r2 >= hi.max(hj).powi(2) {
                return;
            }
            let mj = sc.m(j);
            rho += mj * poly6_sym(r2, hi, hj);
            let g = spiky_grad_sym(xij, r2.sqrt(), hi, hj) * (mj / rho0);
            grad_i += g;
            sum2 += g.dot(g);
        });
        for_each_wall_neighbor(sc.grid, sc.bcell_start, sc.bpos, p, |_, xik| {
            let r2 = xik.dot(xik);
            if r2 >= hi.max(h0).powi(2) {
                return;
            }
            // wall particles weigh m0 whatever the fluid particle's level
            rho += m0 * poly6_sym(r2, hi, h0);
            near_wall = true;
            grad_i += wall_grad(sc.prm, spiky_grad_sym(xik, r2.sqrt(), hi, h0)) * (m0 / rho0);
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
        lam.push(-c / (sum2 + grad_i.dot(grad_i) + sc.prm.eps as f64));
        den.push(rho);
    }
    (lam, den)
}

/// The lambda in a scratch word written by compute_lambda (shaders/pbf.wgsl `lam_pack`): with
/// more than one level its 3 low mantissa bits carry the particle's level, cleared here.
pub fn lambda_of_word(w: f32, single_level: bool) -> f64 {
    if single_level {
        return w as f64;
    }
    f32::from_bits(w.to_bits() & !7) as f64
}

/// A wall particle's kernel gradient; with `domain.free_slip` its y part alone (the shader's
/// `wall_grad`).
fn wall_grad(prm: &PbfParams, g: DVec3) -> DVec3 {
    if prm.free_slip != 0 {
        DVec3::new(0.0, g.y, 0.0)
    } else {
        g
    }
}

/// Returns the corrected predicted positions p* + delta p (confined).
pub fn compute_delta(sc: &Scene, pred: &[V3], lambda: &[f64]) -> Vec<V3> {
    compute_delta_in(sc, pred, lambda, None)
}

/// compute_delta over fixed neighbour sets (the shader's; None: all pairs).
pub fn compute_delta_in(
    sc: &Scene,
    pred: &[V3],
    lambda: &[f64],
    sets: Option<&[Vec<usize>]>,
) -> Vec<V3> {
    let rho0 = sc.prm.rest_density as f64;
    let h0 = sc.prm.h0 as f64;
    pred.iter()
        .enumerate()
        .map(|(i, &p)| {
            let (hi, mi, li) = (sc.h(i), sc.m(i), lambda[i]);
            let mut dp = DVec3::ZERO;
            fluid_pairs(sc, pred, sets, i, |j, xij| {
                let r2 = xij.dot(xij);
                let hj = sc.h(j);
                if r2 >= hi.max(hj).powi(2) {
                    return;
                }
                let mj = sc.m(j);
                let s = li * mj + lambda[j] * mi + sc.scorr(r2, hi, hj) * mj;
                dp += spiky_grad_sym(xij, r2.sqrt(), hi, hj) * s;
            });
            for_each_wall_neighbor(sc.grid, sc.bcell_start, sc.bpos, p, |_, xik| {
                let r2 = xik.dot(xik);
                if r2 >= hi.max(h0).powi(2) {
                    return;
                }
                let s = (li + sc.scorr(r2, hi, h0)) * sc.prm.m0 as f64;
                dp += wall_grad(sc.prm, spiky_grad_sym(xik, r2.sqrt(), hi, h0)) * s;
            });
            confine(sc.grid, DVec3::from(p) + dp * (1.0 / rho0)).to_array()
        })
        .collect()
}

pub fn update_velocity(grid: &GridParams, prm: &PbfParams, pos: &[V3], pred: &[V3]) -> Vec<V3> {
    let size = domain_size(grid);
    let per = [grid.periodic_x(), grid.periodic_z()];
    pos.iter()
        .zip(pred)
        .map(|(&x, &p)| {
            (min_image(DVec3::from(p) - DVec3::from(x), size, per) * prm.inv_dt as f64).to_array()
        })
        .collect()
}

/// Returns (omega, |omega|) per particle.
pub fn vorticity(sc: &Scene, pred: &[V3], vel: &[V3], density: &[f64]) -> Vec<[f64; 4]> {
    pred.iter()
        .enumerate()
        .map(|(i, &p)| {
            let hi = sc.h(i);
            let mut w = DVec3::ZERO;
            for_each_neighbor(sc.grid, sc.cell_start, pred, p, |j, xij| {
                let r2 = xij.dot(xij);
                let hj = sc.h(j);
                if r2 >= hi.max(hj).powi(2) {
                    return;
                }
                let vj = sc.m(j) / density[j];
                let g = spiky_grad_sym(xij, r2.sqrt(), hi, hj);
                w += (DVec3::from(vel[i]) - DVec3::from(vel[j])).cross(g) * vj;
            });
            w.extend(w.length()).to_array()
        })
        .collect()
}

/// XSPH + vorticity confinement + speed clamp; `omega` is ignored when vorticity is 0. (The
/// shader also sums the density over the same pairs and the walls: `compute_lambda_in`'s.)
pub fn viscosity_confine(
    sc: &Scene,
    pred: &[V3],
    vel: &[V3],
    density: &[f64],
    omega: &[[f64; 4]],
) -> Vec<V3> {
    viscosity_confine_in(sc, pred, vel, density, omega, None)
}

/// viscosity_confine over fixed neighbour sets (the shader's without vorticity; None: all).
pub fn viscosity_confine_in(
    sc: &Scene,
    pred: &[V3],
    vel: &[V3],
    density: &[f64],
    omega: &[[f64; 4]],
    sets: Option<&[Vec<usize>]>,
) -> Vec<V3> {
    let use_vort = sc.prm.vorticity > 0.0;
    pred.iter()
        .enumerate()
        .map(|(i, _)| {
            let hi = sc.h(i);
            let wi = if use_vort { omega[i][3] } else { 0.0 };
            let mut acc = DVec3::ZERO;
            let mut eta = DVec3::ZERO;
            fluid_pairs(sc, pred, sets, i, |j, xij| {
                let r2 = xij.dot(xij);
                let hj = sc.h(j);
                if r2 >= hi.max(hj).powi(2) {
                    return;
                }
                let vj = sc.m(j) / density[j];
                let vs = 2.0 * sc.m(j) / (density[i] + density[j]);
                acc += (DVec3::from(vel[j]) - DVec3::from(vel[i])) * (vs * poly6_sym(r2, hi, hj));
                if use_vort {
                    let g = spiky_grad_sym(xij, r2.sqrt(), hi, hj);
                    eta += g * (vj * (omega[j][3] - wi));
                }
            });
            let mut v = DVec3::from(vel[i]) + acc * sc.prm.xsph as f64;
            let le = eta.length();
            if use_vort && le > 0.0 {
                let o = DVec3::from_slice(&omega[i][..3]);
                let a = (eta * (1.0 / le)).cross(o);
                v += a * (sc.prm.dt as f64 * sc.prm.vorticity as f64);
            }
            clamp_speed(sc.prm, v).to_array()
        })
        .collect()
}
