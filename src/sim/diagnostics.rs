//! Cloud diagnostics of a read-back state, for stats.jsonl (see docs/SMOOTHING.md).
//!
//! All sums are f64 in particle index order, so the same state gives the same numbers. The
//! neighbour counts of the isolation measure are integers computed per particle in parallel
//! (order-free) on the CPU cell table.
use crate::config::ShotConfig;
use crate::sim::grid_params::GridParams;
use crate::sim::reference::grid::{build_cell_table, for_each_neighbor};
use crate::sim::ParticleState;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// A particle is cloudy when its cloud content w exceeds this (kg/kg, i.e. 0.01 g/kg: about a
/// hundredth of the liquid water of a fair-weather cumulus, the faintest visible wisp).
pub const CLOUDY_THRESHOLD: f64 = 1.0e-5;

/// A cloudy particle with fewer cloudy neighbours than this within its kernel radius counts
/// as isolated. A particle inside a cloud at rest spacing has about 30 neighbours within
/// h = 2 d; 4 flags lone particles and thin strings.
pub const ISOLATION_NEIGHBORS: usize = 4;

/// Mass of a level-0 particle m0 = rest_density * spacing^3 (kg); level l has m0 2^-l.
pub fn particle_mass0(cfg: &ShotConfig) -> f64 {
    cfg.solver.rest_density * cfg.domain.spacing.powi(3)
}

/// Keys: `total_water` = sum m (v + w) (kg), `cloud_mass` = sum m w (kg), `cloudy_particles`
/// (w > [`CLOUDY_THRESHOLD`]), `temperature_mean` (mass-weighted, K), `temperature_max` (K),
/// `isolation` = fraction of the cloud mass held by cloudy particles with fewer than
/// [`ISOLATION_NEIGHBORS`] cloudy neighbours within their kernel radius h_i (0 when there is
/// no cloud).
pub fn cloud_diagnostics(state: &ParticleState, cfg: &ShotConfig) -> BTreeMap<String, f64> {
    let n = state.len();
    let m0 = particle_mass0(cfg);
    let h0 = cfg.domain.spacing * cfg.domain.kernel_ratio;
    let mass = |i: usize| m0 * (-(state.info[i][1] as f64)).exp2();
    let radius = |i: usize| h0 * (-(state.info[i][1] as f64) / 3.0).exp2();
    let cloudy = |i: usize| state.thermo[i][2] as f64 > CLOUDY_THRESHOLD;

    let mut total_water = 0.0;
    let mut cloud_mass = 0.0;
    let mut cloudy_particles = 0usize;
    let mut total_mass = 0.0;
    let mut t_weighted = 0.0;
    let mut t_max = f64::NEG_INFINITY;
    for i in 0..n {
        let th = state.thermo[i].map(|v| v as f64);
        let m = mass(i);
        total_water += m * (th[1] + th[2]);
        cloud_mass += m * th[2];
        total_mass += m;
        t_weighted += m * th[0];
        t_max = t_max.max(th[0]);
        if cloudy(i) {
            cloudy_particles += 1;
        }
    }

    // Cloudy particles only: a neighbour table over them answers "how many cloudy neighbours".
    let cloudy_idx: Vec<usize> = (0..n).filter(|&i| cloudy(i)).collect();
    let grid = GridParams::for_shot(cfg);
    let cpos: Vec<[f64; 3]> = cloudy_idx
        .iter()
        .map(|&i| {
            let p = state.pos[i];
            [p[0] as f64, p[1] as f64, p[2] as f64]
        })
        .collect();
    let (order, cell_start) = build_cell_table(&grid, &cpos);
    let sorted: Vec<[f64; 3]> = order.iter().map(|&k| cpos[k as usize]).collect();
    let isolated: Vec<bool> = cloudy_idx
        .par_iter()
        .enumerate()
        .map(|(k, &i)| {
            let h2 = radius(i) * radius(i);
            let mut neighbours = 0usize;
            for_each_neighbor(&grid, &cell_start, &sorted, cpos[k], |j, d| {
                let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                if order[j] as usize != k && r2 < h2 {
                    neighbours += 1;
                }
            });
            neighbours < ISOLATION_NEIGHBORS
        })
        .collect();
    let mut isolated_mass = 0.0;
    for (k, &i) in cloudy_idx.iter().enumerate() {
        if isolated[k] {
            isolated_mass += mass(i) * state.thermo[i][2] as f64;
        }
    }

    let mut out = BTreeMap::new();
    out.insert("total_water".into(), total_water);
    out.insert("cloud_mass".into(), cloud_mass);
    out.insert("cloudy_particles".into(), cloudy_particles as f64);
    out.insert(
        "temperature_mean".into(),
        if total_mass > 0.0 {
            t_weighted / total_mass
        } else {
            0.0
        },
    );
    out.insert("temperature_max".into(), if n > 0 { t_max } else { 0.0 });
    out.insert(
        "isolation".into(),
        if cloud_mass > 0.0 {
            isolated_mass / cloud_mass
        } else {
            0.0
        },
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shot() -> ShotConfig {
        serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\ndomain: {size: [100.0, 100.0, 100.0], spacing: 10.0}\n",
        )
        .unwrap()
    }

    fn state(points: &[([f32; 3], f32, f32, u32)]) -> ParticleState {
        ParticleState {
            pos: points
                .iter()
                .map(|p| [p.0[0], p.0[1], p.0[2], 0.0])
                .collect(),
            vel: vec![[0.0; 4]; points.len()],
            thermo: points.iter().map(|p| [p.1, 0.01, p.2, 0.0]).collect(),
            info: points
                .iter()
                .enumerate()
                .map(|(i, p)| [i as u32, p.3])
                .collect(),
            density: vec![1.0; points.len()],
        }
    }

    #[test]
    fn sums_counts_and_isolation() {
        let cfg = shot();
        let m0 = particle_mass0(&cfg);
        // A compact blob of 9 cloudy particles (8 neighbours each within h = 20 m), one lone
        // cloudy particle far away, one clear particle at level 1 (half mass).
        let mut pts = Vec::new();
        for k in 0..9 {
            let p = [
                40.0 + (k % 3) as f32 * 5.0,
                40.0 + (k / 3) as f32 * 5.0,
                50.0,
            ];
            pts.push((p, 290.0, 1e-3, 0));
        }
        pts.push(([5.0, 90.0, 5.0], 280.0, 2e-3, 0));
        pts.push(([90.0, 10.0, 90.0], 300.0, 0.0, 1));
        let d = cloud_diagnostics(&state(&pts), &cfg);
        assert_eq!(d["cloudy_particles"], 10.0);
        let cloud = m0 * (9.0 * 1e-3 + 2e-3);
        assert!(
            (d["cloud_mass"] - cloud).abs() < 1e-6 * cloud,
            "w is stored in f32"
        );
        let water = m0 * (10.0 * 0.01 + 9.0 * 1e-3 + 2e-3) + 0.5 * m0 * 0.01;
        assert!((d["total_water"] - water).abs() < 1e-6 * water);
        assert!((d["isolation"] - 2e-3 / (9.0 * 1e-3 + 2e-3)).abs() < 1e-6);
        assert_eq!(d["temperature_max"], 300.0);
        let tmean = (9.0 * 290.0 + 280.0 + 0.5 * 300.0) / 10.5;
        assert!((d["temperature_mean"] - tmean).abs() < 1e-4);
        // Deterministic.
        assert_eq!(d, cloud_diagnostics(&state(&pts), &cfg));
    }

    #[test]
    fn neighbours_count_across_periodic_faces() {
        let cfg = shot();
        // Five cloudy particles straddling the periodic x face: each has 4 within h.
        let pts: Vec<_> = [1.0f32, 3.0, 97.0, 99.0, 95.0]
            .iter()
            .map(|&x| ([x, 50.0, 50.0], 290.0, 1e-3, 0))
            .collect();
        let d = cloud_diagnostics(&state(&pts), &cfg);
        assert_eq!(d["isolation"], 0.0);
        let empty = cloud_diagnostics(&state(&[]), &cfg);
        assert_eq!(empty["isolation"], 0.0);
        assert_eq!(empty["cloud_mass"], 0.0);
    }
}
