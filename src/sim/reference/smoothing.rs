//! f64 mirror of shaders/smoothing.wgsl (`smooth_temperature`): one Jacobi iteration of the
//! temperature-smoothing constraint (eqs. 12-17). Arrays are in cell order, as on the GPU.
use super::common::spiky_grad_sym;
use super::grid::{for_each_neighbor, for_each_wall_neighbor};
use crate::sim::grid_params::GridParams;
use crate::sim::smoothing::SmoothParams;
use glam::DVec3;

/// The particle side of one smoothing iteration (cell-ordered arrays).
pub struct SmoothInput<'a> {
    pub grid: &'a GridParams,
    pub params: &'a SmoothParams,
    pub pos: &'a [[f64; 3]],
    pub level: &'a [u32],
    pub temperature: &'a [f64],
    pub cell_start: &'a [u32],
    /// Boundary particles (xyz, temperature) in cell order, and their cell table.
    pub boundary: &'a [[f64; 4]],
    /// The wall particles' table (`build_wall_table`: the first and last y rows only).
    pub boundary_cell_start: &'a [u32],
}

fn radius_of_level(p: &SmoothParams, level: u32) -> f64 {
    p.h0 as f64 * (-(level as f64) / 3.0).exp2()
}

fn laplacian_coefficient(p: &SmoothParams, xij: DVec3, hi: f64, hj: f64, volume: f64) -> f64 {
    let r2 = xij.dot(xij);
    let hmax = hi.max(hj);
    if r2 >= hmax * hmax {
        return 0.0;
    }
    let r = r2.sqrt();
    let g = spiky_grad_sym(xij, r, hi, hj);
    volume * xij.dot(g) / (r2 + p.epsilon as f64)
}

/// `(S_i, sum_k a_ik^2, C_i)` of particle i: the diagonal of the constraint gradient (eq. 16),
/// the sum of squares of its off-diagonal entries, and the constraint value (eq. 13).
pub fn constraint_terms(input: &SmoothInput, i: usize) -> (f64, f64, f64) {
    let p = input.params;
    let xi = input.pos[i];
    let hi = radius_of_level(p, input.level[i]);
    let ti = input.temperature[i];
    let (mut sum_a, mut sum_a2, mut c) = (0.0, 0.0, 0.0);
    for_each_neighbor(input.grid, input.cell_start, input.pos, xi, |j, xij| {
        if j == i {
            return;
        }
        let lj = input.level[j];
        let volume = p.volume0 as f64 * (-(lj as f64)).exp2();
        let a = laplacian_coefficient(p, xij, hi, radius_of_level(p, lj), volume);
        sum_a += a;
        sum_a2 += a * a;
        c += a * (ti - input.temperature[j]);
    });
    if p.fixed_walls == 0 {
        return (sum_a, sum_a2, c);
    }
    let bpos: Vec<[f64; 3]> = input.boundary.iter().map(|b| [b[0], b[1], b[2]]).collect();
    for_each_wall_neighbor(
        input.grid,
        input.boundary_cell_start,
        &bpos,
        xi,
        |k, xik| {
            let a = laplacian_coefficient(p, xik, hi, p.h0 as f64, p.volume0 as f64);
            sum_a += a;
            sum_a2 += a * a;
            c += a * (ti - input.boundary[k][3]);
        },
    );
    (sum_a, sum_a2, c)
}

/// One Jacobi iteration of the conservative form (`physics.smoothing.conservative`), of the
/// dry static temperature s = T + Gamma_d y (Gamma_d = `lapse`):
/// T*_i = T_i - sum_j (k_i + k_j) / 2 a_ij (s_i - s_j) - sum_walls k_i a_ik (s_i - s_k) with
/// k_i = kappa S_i / (S_i^2 + sum_k a_ik^2), the walls only when they are fixed. Exact here; the
/// GPU adds each T_i's flux with stochastic rounding (`add_unbiased`), equal on average.
pub fn smooth_temperature_conservative(input: &SmoothInput) -> Vec<f64> {
    let p = input.params;
    let kappa = p.kappa as f64;
    let lapse = p.lapse as f64;
    let k: Vec<f64> = (0..input.pos.len())
        .map(|i| {
            let (s, s2, _) = constraint_terms(input, i);
            let g = s * s + s2;
            if g > 0.0 {
                kappa * s / g
            } else {
                0.0
            }
        })
        .collect();
    let bpos: Vec<[f64; 3]> = input.boundary.iter().map(|b| [b[0], b[1], b[2]]).collect();
    (0..input.pos.len())
        .map(|i| {
            let hi = radius_of_level(p, input.level[i]);
            let ti = input.temperature[i];
            let mut flux = 0.0;
            for_each_neighbor(
                input.grid,
                input.cell_start,
                input.pos,
                input.pos[i],
                |j, xij| {
                    if j == i {
                        return;
                    }
                    let lj = input.level[j];
                    let volume = p.volume0 as f64 * (-(lj as f64)).exp2();
                    let a = laplacian_coefficient(p, xij, hi, radius_of_level(p, lj), volume);
                    let ds = ti - input.temperature[j] + lapse * xij.y;
                    flux += 0.5 * (k[i] + k[j]) * a * ds;
                },
            );
            if p.fixed_walls != 0 {
                let (grid, cells) = (input.grid, input.boundary_cell_start);
                for_each_wall_neighbor(grid, cells, &bpos, input.pos[i], |w, xik| {
                    let a = laplacian_coefficient(p, xik, hi, p.h0 as f64, p.volume0 as f64);
                    flux += k[i] * a * (ti - input.boundary[w][3] + lapse * xik.y);
                });
            }
            ti - flux
        })
        .collect()
}

/// The SPH Laplacian of the temperature of every particle (eq. 13, with the volumes V_j).
pub fn temperature_laplacian(input: &SmoothInput) -> Vec<f64> {
    (0..input.pos.len())
        .map(|i| constraint_terms(input, i).2)
        .collect()
}

/// Mirror of the `smooth_temperature` entry: the smoothed temperatures T* (eq. 17).
pub fn smooth_temperature(input: &SmoothInput) -> Vec<f64> {
    let kappa = input.params.kappa as f64;
    (0..input.pos.len())
        .map(|i| {
            let (s, s2, c) = constraint_terms(input, i);
            let g = s * s + s2;
            let t = input.temperature[i];
            if g > 0.0 {
                t - kappa * c * s / g
            } else {
                t
            }
        })
        .collect()
}

/// `(j, a_ij)` of every vapor-mixing pair of particle i: fluid neighbours j != i for which i or
/// j holds cloud water (`cloud` > 0), or every one with `mix_everywhere`.
fn mixing_pairs(input: &SmoothInput, cloud: &[f64], i: usize, mut f: impl FnMut(usize, f64)) {
    let p = input.params;
    let xi = input.pos[i];
    let hi = radius_of_level(p, input.level[i]);
    let everywhere = p.mix_everywhere != 0;
    for_each_neighbor(input.grid, input.cell_start, input.pos, xi, |j, xij| {
        if j == i || !(everywhere || cloud[i] > 0.0 || cloud[j] > 0.0) {
            return;
        }
        let lj = input.level[j];
        let volume = p.volume0 as f64 * (-(lj as f64)).exp2();
        let a = laplacian_coefficient(p, xij, hi, radius_of_level(p, lj), volume);
        if a != 0.0 {
            f(j, a);
        }
    });
}

/// Mirror of the `vapor_limit` entry: l_i = min(1, 0.5 / (vapor_rate sum_j |a_ij|)).
pub fn vapor_limits(input: &SmoothInput, cloud: &[f64]) -> Vec<f64> {
    let rate = input.params.vapor_rate as f64;
    (0..input.pos.len())
        .map(|i| {
            let mut sum = 0.0;
            mixing_pairs(input, cloud, i, |_, a| sum += a.abs());
            let demand = rate * sum;
            if demand > 0.0 {
                (0.5 / demand).min(1.0)
            } else {
                1.0
            }
        })
        .collect()
}

/// Mirror of the vapor mixing the `smooth_temperature` entry applies in the same pass (.y of
/// thermo): `v*_i = v_i + vapor_rate sum_j min(l_i, l_j) a_ij (v_i - v_j)` over the mixing pairs
/// ([`vapor_limits`] first).
pub fn mix_vapor(input: &SmoothInput, vapor: &[f64], cloud: &[f64]) -> Vec<f64> {
    let rate = input.params.vapor_rate as f64;
    if rate <= 0.0 {
        return vapor.to_vec();
    }
    let limit = vapor_limits(input, cloud);
    (0..input.pos.len())
        .map(|i| {
            let mut c = 0.0;
            mixing_pairs(input, cloud, i, |j, a| {
                c += limit[i].min(limit[j]) * a * (vapor[i] - vapor[j]);
            });
            vapor[i] + rate * c
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::reference::grid::{build_cell_table, build_wall_table};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Cell-ordered particles of a jittered lattice (spacing 1, h0 = 2) in an 8^3 box,
    /// periodic in x and z, with two layers of boundary particles under the floor and above
    /// the ceiling.
    pub(crate) struct Scene {
        pub grid: GridParams,
        pub pos: Vec<[f64; 3]>,
        pub level: Vec<u32>,
        pub cell_start: Vec<u32>,
        pub boundary: Vec<[f64; 4]>,
        pub boundary_cell_start: Vec<u32>,
    }

    pub(crate) fn scene(seed: u64, levels: bool, floor_t: f64, ceiling_t: f64) -> Scene {
        let n = 8;
        let grid = GridParams::new([n as f64; 3], 2.0, true, true);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pos = Vec::new();
        let mut level: Vec<u32> = Vec::new();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let jit = |r: &mut ChaCha8Rng| r.random_range(-0.2..0.2);
                    pos.push([
                        i as f64 + 0.5 + jit(&mut rng),
                        j as f64 + 0.5 + jit(&mut rng),
                        k as f64 + 0.5 + jit(&mut rng),
                    ]);
                    level.push(if levels { rng.random_range(0..3) } else { 0 });
                }
            }
        }
        let mut bpos = Vec::new();
        let mut btemp = Vec::new();
        for i in 0..n {
            for k in 0..n {
                for (y, t) in [
                    (-0.5, floor_t),
                    (-1.5, floor_t),
                    (n as f64 + 0.5, ceiling_t),
                    (n as f64 + 1.5, ceiling_t),
                ] {
                    bpos.push([i as f64 + 0.5, y, k as f64 + 0.5]);
                    btemp.push(t);
                }
            }
        }
        let (order, cell_start) = build_cell_table(&grid, &pos);
        let (border, boundary_cell_start) = build_wall_table(&grid, &bpos);
        Scene {
            grid,
            pos: order.iter().map(|&o| pos[o as usize]).collect(),
            level: order.iter().map(|&o| level[o as usize]).collect(),
            cell_start,
            boundary: border
                .iter()
                .map(|&o| {
                    let p = bpos[o as usize];
                    [p[0], p[1], p[2], btemp[o as usize]]
                })
                .collect(),
            boundary_cell_start,
        }
    }

    fn params(kappa: f32) -> SmoothParams {
        SmoothParams {
            lapse: 0.0,
            h0: 2.0,
            kappa,
            epsilon: 1e-2,
            volume0: 1.0,
            fixed_walls: 1,
            vapor_rate: 0.0,
            conservative: 0,
            mix_everywhere: 0,
            _pad: [0; 3],
        }
    }

    fn input<'a>(s: &'a Scene, p: &'a SmoothParams, t: &'a [f64]) -> SmoothInput<'a> {
        SmoothInput {
            grid: &s.grid,
            params: p,
            pos: &s.pos,
            level: &s.level,
            temperature: t,
            cell_start: &s.cell_start,
            boundary: &s.boundary,
            boundary_cell_start: &s.boundary_cell_start,
        }
    }

    /// Standard deviation of a field.
    fn spread(t: &[f64]) -> f64 {
        let mean = t.iter().sum::<f64>() / t.len() as f64;
        (t.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / t.len() as f64).sqrt()
    }

    fn norm2(v: &[f64]) -> f64 {
        v.iter().map(|c| c * c).sum()
    }

    /// sum (lap T)^2 drops at every iteration, for the paper's kappa and for kappa = 1, with
    /// mixed particle sizes and boundary particles of fixed temperature.
    #[test]
    fn smoothing_lowers_laplacian_norm_every_iteration() {
        for (seed, levels, kappa) in [
            (1, false, 0.1),
            (2, true, 0.1),
            (3, false, 1.0),
            (4, true, 1.0),
        ] {
            let s = scene(seed, levels, 296.0, 284.0);
            let p = params(kappa);
            let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
            let mut t: Vec<f64> = (0..s.pos.len())
                .map(|_| rng.random_range(280.0..300.0))
                .collect();
            let mut prev = norm2(&temperature_laplacian(&input(&s, &p, &t)));
            let first = prev;
            for it in 0..20 {
                t = smooth_temperature(&input(&s, &p, &t));
                let now = norm2(&temperature_laplacian(&input(&s, &p, &t)));
                assert!(
                    now < prev,
                    "kappa {kappa} levels {levels}: iteration {it}: {prev} -> {now}"
                );
                prev = now;
            }
            println!("kappa {kappa} levels {levels}: sum C^2 {first:.4e} -> {prev:.4e}");
            assert!(prev < 0.9 * first);
        }
    }

    /// kappa is a rate (per solver.reference_step): one substep of 4 s and four of 1 s smooth a
    /// two-slab field alike. Measured: the spread drops by 0.0814 and 0.0833 K (2.4% apart;
    /// tolerance 5%); with kappa per substep four substeps smooth 3.6 times as much.
    #[test]
    fn smoothing_per_second_does_not_depend_on_the_substeps() {
        let cfg: crate::config::ShotConfig = serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\ndomain: {size: [8, 8, 8], spacing: 1.0}\n",
        )
        .unwrap();
        let s = scene(9, true, 295.0, 295.0);
        let t0: Vec<f64> = s
            .pos
            .iter()
            .map(|p| if p[0] < 4.0 { 290.0 } else { 300.0 })
            .collect();
        let run = |dt: f64, substeps: usize, per_substep: bool| {
            let mut p = SmoothParams::new(&cfg, dt);
            if per_substep {
                p.kappa = cfg.physics.smoothing.kappa as f32;
            }
            let mut t = t0.clone();
            for _ in 0..substeps {
                t = smooth_temperature(&input(&s, &p, &t));
            }
            spread(&t)
        };
        let (start, one, four) = (spread(&t0), run(4.0, 1, false), run(1.0, 4, false));
        let four_fixed = run(1.0, 4, true);
        println!("spread {start:.4} -> 1 x 4 s {one:.4}, 4 x 1 s {four:.4}, kappa per substep {four_fixed:.4}");
        assert!(one < 0.99 * start, "smoothing did something");
        assert!(
            ((one - four) / (start - one)).abs() < 0.05,
            "{one} vs {four}"
        );
        assert!(
            four_fixed < four - 0.5 * (start - one),
            "the per-substep kappa is the bug"
        );
    }

    /// A field of two values (two slabs) is flattened by a large kappa; the paper's kappa = 0.1
    /// keeps much more of the step over the same iterations.
    #[test]
    fn large_kappa_flattens_a_two_valued_field() {
        let s = scene(7, false, 295.0, 295.0);
        let t0: Vec<f64> = s
            .pos
            .iter()
            .map(|p| if p[0] < 4.0 { 290.0 } else { 300.0 })
            .collect();
        let run = |kappa: f32, iterations: usize| {
            let p = params(kappa);
            let mut t = t0.clone();
            for _ in 0..iterations {
                t = smooth_temperature(&input(&s, &p, &t));
            }
            t
        };
        let big = run(1.0, 60);
        let small = run(0.1, 60);
        let (s0, sb, ss) = (spread(&t0), spread(&big), spread(&small));
        println!("std of T: initial {s0:.3}, kappa 1: {sb:.4}, kappa 0.1: {ss:.4}");
        assert!(sb < 0.05 * s0, "kappa = 1 leaves std {sb} of {s0}");
        assert!(
            ss > 3.0 * sb,
            "kappa = 0.1 should smooth less: {ss} vs {sb}"
        );
        let (lo, hi) = big
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(hi - lo < 1.0, "range {lo}..{hi}");
    }

    /// A uniform field (fluid and boundary at the same temperature) is a fixed point.
    #[test]
    fn uniform_field_is_unchanged() {
        let s = scene(9, true, 291.0, 291.0);
        let p = params(1.0);
        let t = vec![291.0; s.pos.len()];
        let out = smooth_temperature(&input(&s, &p, &t));
        assert!(out.iter().all(|&v| (v - 291.0).abs() < 1e-9));
    }

    /// Vapor values in [0, 0.02), one per particle.
    fn random_vapor(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| rng.random_range(0.0..0.02)).collect()
    }

    /// Cloud water on every other particle.
    fn every_other_cloudy(n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| if i % 2 == 0 { 1e-3 } else { 0.0 })
            .collect()
    }

    /// Mixing at 100 times the rate a lattice could take explicitly (2 h_min^2 / 40 x 100).
    fn fast_mixing_params(mix_everywhere: u32) -> SmoothParams {
        let mut p = params(0.0);
        let h_min = 2.0 * (-2.0f64 / 3.0).exp2();
        p.vapor_rate = (100.0 * 2.0 * h_min * h_min / 40.0) as f32;
        p.mix_everywhere = mix_everywhere;
        p
    }

    /// 50 mixing iterations from `v0`: the limiter keeps every value in the initial range,
    /// sum m_i v_i (m_i = 2^-l_i) is kept to rounding, and the field flattens. Returns it.
    fn mix_50_conserving(s: &Scene, p: &SmoothParams, v0: &[f64], cloud: &[f64]) -> Vec<f64> {
        let mass = |v: &[f64]| -> f64 {
            v.iter()
                .zip(&s.level)
                .map(|(v, &l)| v * (-(l as f64)).exp2())
                .sum()
        };
        let t = vec![295.0; s.pos.len()];
        let mut v = v0.to_vec();
        for _ in 0..50 {
            v = mix_vapor(&input(s, p, &t), &v, cloud);
            let (lo, hi) = v
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(lo >= 0.0 && hi <= 0.02, "range {lo}..{hi}");
        }
        let (m0, m1) = (mass(v0), mass(&v));
        println!(
            "vapor mass {m0:.12} -> {m1:.12}; spread {} -> {}",
            spread(v0),
            spread(&v)
        );
        assert!(((m1 - m0) / m0).abs() < 1e-12, "{m0} -> {m1}");
        assert!(spread(&v) < 0.3 * spread(v0));
        v
    }

    /// Vapor mixing moves vapor and creates none, with mixed levels and every other particle
    /// cloudy, and the limiter holds it at 100 times the explicit rate (`mix_50_conserving`).
    /// Clear air does not mix, and rate 0 changes nothing.
    #[test]
    fn vapor_mixing_conserves_and_stays_in_range() {
        let s = scene(11, true, 295.0, 295.0);
        let mut p = fast_mixing_params(0);
        let v0 = random_vapor(s.pos.len(), 12);
        let t = vec![295.0; s.pos.len()];
        let cloud = every_other_cloudy(s.pos.len());
        let clear = vec![0.0; s.pos.len()];
        assert_eq!(mix_vapor(&input(&s, &p, &t), &v0, &clear), v0);
        mix_50_conserving(&s, &p, &v0, &cloud);
        // rate 0 leaves the field exactly as it was
        p.vapor_rate = 0.0;
        assert_eq!(mix_vapor(&input(&s, &p, &t), &v0, &cloud), v0);
    }

    /// `vapor_mixing: everywhere`: clear air mixes too, and still creates no vapor and keeps
    /// every value in the initial range at 100 times the explicit rate; a step mixes every pair
    /// the cloud-edge mode mixes and more, so it flattens the field further.
    #[test]
    fn vapor_mixing_everywhere_mixes_clear_air_and_conserves() {
        let s = scene(11, true, 295.0, 295.0);
        let p = fast_mixing_params(1);
        let v0 = random_vapor(s.pos.len(), 13);
        let t = vec![295.0; s.pos.len()];
        let clear = vec![0.0; s.pos.len()];
        let once = mix_vapor(&input(&s, &p, &t), &v0, &clear);
        assert_ne!(once, v0, "clear air must mix");
        mix_50_conserving(&s, &p, &v0, &clear);
        // every pair mixes, so one step flattens more than at cloud edges alone
        let edges = fast_mixing_params(0);
        let at_edges = mix_vapor(
            &input(&s, &edges, &t),
            &v0,
            &every_other_cloudy(s.pos.len()),
        );
        assert!(
            spread(&once) < spread(&at_edges),
            "{} vs {}",
            spread(&once),
            spread(&at_edges)
        );
    }
}
