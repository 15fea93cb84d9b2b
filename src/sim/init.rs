//! Initial state (paper section 5), computed on the CPU in f64 and uploaded once.
//!
//! Why the CPU: it runs once per shot, is a handful of closed-form expressions per particle, and
//! computing it in f64 on the host makes it exactly reproducible on every adapter (no f32
//! transcendental differences between GPU vendors) with nothing to mirror or to checkpoint. The
//! random velocities come from a stateless hash of (seed, particle index), so there is no RNG
//! state either.
use crate::config::ShotConfig;
use crate::ground::ParticleState;
use crate::sim::grid_params::GridParams;
use crate::sim::thermo::{environment_temperature, initial_thermo};

/// splitmix64 finaliser.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform number in [0, 1) from (seed, particle index, draw number): stateless.
pub fn hash_uniform(seed: u64, index: u64, draw: u64) -> f64 {
    let h = mix(mix(seed ^ mix(index)).wrapping_add(draw));
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The fluid particles: a uniform lattice filling the box, random velocity directions with speeds
/// uniform in [0, initial_speed] (plus `physics.wind.initial` at their height), T = T0(y), cloud w = 0, vapor v = kv * gamma(T), level 0, id = index;
/// below `environment.perturbation.height`, T and v offset uniformly within its amplitudes.
pub fn initial_particles(cfg: &ShotConfig) -> ParticleState {
    let (n, d) = cfg.domain.lattice();
    let count = n[0] * n[1] * n[2];
    let mut s = ParticleState {
        pos: Vec::with_capacity(count),
        vel: Vec::with_capacity(count),
        thermo: Vec::with_capacity(count),
        info: Vec::with_capacity(count),
        density: vec![cfg.solver.rest_density as f32; count],
    };
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                let idx = s.pos.len() as u64;
                let p = [
                    (i as f64 + 0.5) * d[0],
                    (j as f64 + 0.5) * d[1],
                    (k as f64 + 0.5) * d[2],
                ];
                let cos_t = 2.0 * hash_uniform(cfg.seed, idx, 0) - 1.0;
                let phi = 2.0 * std::f64::consts::PI * hash_uniform(cfg.seed, idx, 1);
                let speed = cfg.physics.initial_speed * hash_uniform(cfg.seed, idx, 2);
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                let mut v = [
                    speed * sin_t * phi.cos(),
                    speed * cos_t,
                    speed * sin_t * phi.sin(),
                ];
                if let Some(u) = crate::sim::wind::initial_at(cfg, p[1]) {
                    v[0] += u[0];
                    v[2] += u[1];
                }
                s.pos.push([p[0] as f32, p[1] as f32, p[2] as f32, 0.0]);
                s.vel.push([v[0] as f32, v[1] as f32, v[2] as f32, 0.0]);
                let mut thermo = initial_thermo(&cfg.physics, p[1]);
                if let Some(pt) = &cfg.physics.environment.perturbation {
                    if p[1] < pt.height {
                        let dt = pt.temperature * (2.0 * hash_uniform(cfg.seed, idx, 3) - 1.0);
                        let dv = pt.vapor * (2.0 * hash_uniform(cfg.seed, idx, 4) - 1.0);
                        thermo[0] = (f64::from(thermo[0]) + dt) as f32;
                        thermo[1] = (f64::from(thermo[1]) + dv).max(0.0) as f32;
                    }
                }
                s.thermo.push(thermo);
                s.info.push([idx as u32, 0]);
            }
        }
    }
    s
}

/// Layers of wall particles at the floor and at the ceiling: spaced d, down to depth h0.
fn wall_layers(cfg: &ShotConfig) -> usize {
    let (_, d) = cfg.domain.lattice();
    ((cfg.domain.kernel_radius() / d[1] - 0.5).ceil() as usize).max(1)
}

/// How many wall particles [`boundary_particles`] makes (without making them).
pub fn boundary_count(cfg: &ShotConfig) -> usize {
    let (n, _) = cfg.domain.lattice();
    2 * wall_layers(cfg) * n[0] * n[2]
}

/// Floor and ceiling walls: the x/z lattice, layers spaced d below y = 0 and above y = size
/// down to depth h0 (so a fluid particle at the wall has a full neighbourhood), w = the
/// environment temperature of the floor (ceiling). Returned in cell order with their wall table
/// (`build_wall_table`: the first and last y rows of cells only).
pub fn boundary_particles(cfg: &ShotConfig, grid: &GridParams) -> (Vec<[f32; 4]>, Vec<u32>) {
    let (n, d) = cfg.domain.lattice();
    let layers = wall_layers(cfg);
    let size_y = cfg.domain.size[1];
    let t_floor = environment_temperature(&cfg.physics, 0.0);
    let t_ceil = environment_temperature(&cfg.physics, size_y);
    let mut pts: Vec<[f64; 4]> = Vec::new();
    for (wall, t) in [(0, t_floor), (1, t_ceil)] {
        for l in 0..layers {
            let off = (l as f64 + 0.5) * d[1];
            let y = if wall == 0 { -off } else { size_y + off };
            for k in 0..n[2] {
                for i in 0..n[0] {
                    pts.push([(i as f64 + 0.5) * d[0], y, (k as f64 + 0.5) * d[2], t]);
                }
            }
        }
    }
    let p3: Vec<[f64; 3]> = pts.iter().map(|p| [p[0], p[1], p[2]]).collect();
    let (order, cell_start) = crate::sim::cell_table::build_wall_table(grid, &p3);
    let sorted = order
        .iter()
        .map(|&o| pts[o as usize].map(|v| v as f32))
        .collect();
    (sorted, cell_start)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perturbation_stays_below_its_height_and_within_its_amplitudes() {
        let mut cfg: ShotConfig = serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [800.0, 800.0, 800.0], spacing: 50.0}\n",
        )
        .unwrap();
        let calm = initial_particles(&cfg);
        cfg.physics.environment.perturbation = Some(crate::config::Perturbation {
            temperature: 0.1,
            vapor: 2.5e-5,
            height: 400.0,
        });
        let moved = initial_particles(&cfg);
        assert_eq!(calm.pos, moved.pos);
        assert_eq!(calm.vel, moved.vel);
        let (mut below, mut sum_t, mut sum_v, mut max_t, mut max_v) = (0, 0.0, 0.0, 0.0f64, 0.0f64);
        for ((p, a), b) in calm.pos.iter().zip(&calm.thermo).zip(&moved.thermo) {
            let dt = f64::from(b[0]) - f64::from(a[0]);
            let dv = f64::from(b[1]) - f64::from(a[1]);
            if p[1] >= 400.0 {
                assert_eq!(a, b, "untouched above the height");
                continue;
            }
            below += 1;
            sum_t += dt;
            sum_v += dv;
            max_t = max_t.max(dt.abs());
            max_v = max_v.max(dv.abs());
        }
        assert_eq!(below, 16 * 16 * 8);
        // f32 rounding of ~290 K is 3e-5 K; of ~0.01 kg/kg, 1e-9.
        assert!(max_t <= 0.1 + 1e-4 && max_t > 0.09, "{max_t}");
        assert!(max_v <= 2.5e-5 + 1e-8 && max_v > 2.2e-5, "{max_v}");
        // Uniform draws: means near 0 (sd of the mean 0.1/sqrt(3*2048) = 1.3e-3 K).
        assert!((sum_t / below as f64).abs() < 5e-3, "{sum_t}");
        assert!((sum_v / below as f64).abs() < 1.3e-6, "{sum_v}");
    }

    #[test]
    fn hash_is_uniform_and_stateless() {
        let n = 20000;
        let mean: f64 = (0..n).map(|i| hash_uniform(7, i, 0)).sum::<f64>() / n as f64;
        assert!((mean - 0.5).abs() < 0.01, "mean {mean}");
        assert_eq!(hash_uniform(7, 123, 2), hash_uniform(7, 123, 2));
        assert_ne!(hash_uniform(7, 123, 2), hash_uniform(8, 123, 2));
    }
}
