//! Cloud and atmosphere diagnostics of a read-back state, for stats.jsonl (docs/PHYSICS.md).
//!
//! All sums are f64 in particle index order, so the same state gives the same numbers. The
//! neighbour counts of the isolation measure are integers computed per particle in parallel
//! (order-free) on the CPU cell table.
use crate::config::ShotConfig;
use crate::ground::levels;
use crate::ground::ParticleState;
use crate::sim::cell_table::{build_cell_table, for_each_neighbor};
use crate::sim::grid_params::GridParams;
use glam::Vec4;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// A particle is cloudy when its cloud content w exceeds this (kg/kg, i.e. 0.01 g/kg: about a
/// hundredth of the liquid water of a fair-weather cumulus, the faintest visible wisp).
pub const CLOUDY_THRESHOLD: f64 = 1.0e-5;

/// A cloudy particle with fewer cloudy neighbours than this within its kernel radius counts
/// as isolated. A particle inside a cloud at rest spacing has about 30 neighbours within
/// h = 2 d; 4 flags lone particles and thin strings.
pub const ISOLATION_NEIGHBORS: usize = 4;

/// Keys, with m = the cell mass 2^-level (`ShotConfig::cell_mass`): `total_water` =
/// sum m (v + w) (kg), `cloud_mass` = sum m w (kg), `cloudy_particles`
/// (w > [`CLOUDY_THRESHOLD`]), `temperature_mean` (mass-weighted, K), `temperature_max` (K),
/// `isolation` = fraction of the cloud mass held by cloudy particles with fewer than
/// [`ISOLATION_NEIGHBORS`] cloudy neighbours within their kernel radius h_i (0 when there is
/// no cloud).
pub fn cloud_diagnostics(state: &ParticleState, cfg: &ShotConfig) -> CloudDiagnostics {
    let n = state.len();
    // the air a particle stands for (`ShotConfig::cell_mass`), not the solver's m0
    let m0 = cfg.cell_mass();
    let h0 = cfg.domain.kernel_radius();
    let mass = |i: usize| levels::mass(m0, state.info[i][1]);
    let radius = |i: usize| levels::radius(h0, state.info[i][1]);
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
                let r2 = d.length_squared();
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

    CloudDiagnostics {
        total_water,
        cloud_mass,
        cloudy_particles: cloudy_particles as u64,
        temperature_mean: if total_mass > 0.0 {
            t_weighted / total_mass
        } else {
            0.0
        },
        temperature_max: if n > 0 { t_max } else { 0.0 },
        isolation: if cloud_mass > 0.0 {
            isolated_mass / cloud_mass
        } else {
            0.0
        },
    }
}

/// The cloud's figures of a frame ([`cloud_diagnostics`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CloudDiagnostics {
    pub total_water: f64,
    pub cloud_mass: f64,
    pub cloudy_particles: u64,
    pub temperature_mean: f64,
    pub temperature_max: f64,
    pub isolation: f64,
}

impl CloudDiagnostics {
    /// Adds the figures under their stats.jsonl names.
    pub fn insert_into(&self, out: &mut BTreeMap<String, f64>) {
        for (k, v) in [
            ("total_water", self.total_water),
            ("cloud_mass", self.cloud_mass),
            ("cloudy_particles", self.cloudy_particles as f64),
            ("temperature_mean", self.temperature_mean),
            ("temperature_max", self.temperature_max),
            ("isolation", self.isolation),
        ] {
            out.insert(k.to_string(), v);
        }
    }
}

/// Horizontal layers of the per-layer mass ratio.
pub const MASS_LAYERS: usize = 10;

/// Initial mass of each of [`MASS_LAYERS`] equal horizontal layers (units of m0), from the
/// initial lattice (`DomainConfig::lattice`) spread as in [`spread_over_layers`]: the reference of
/// `layer_mass_ratio_*`.
pub fn initial_layer_mass(cfg: &ShotConfig) -> Vec<f64> {
    let (n, d) = cfg.domain.lattice();
    let mut out = vec![0.0; MASS_LAYERS];
    let per_row = (n[0] * n[2]) as f64;
    for j in 0..n[1] {
        let y = (j as f64 + 0.5) * d[1];
        spread_over_layers(&mut out, cfg.domain.size[1], y, d[1], per_row);
    }
    out
}

/// Adds `mass` to the layers, spread with a tent of half-width s (s = the particle's spacing,
/// d 2^(-l/3); cloud-in-cell weights) clipped to the box and renormalised: a lattice fills the
/// height evenly, and a row that moves a metre across a layer face moves a metre's worth of
/// mass, not the whole row (with ~2.4 rows a layer, counting whole rows swings a layer's mass by
/// 30%, and a box of width s still by a few percent where the packing changes near a wall).
fn spread_over_layers(layers: &mut [f64], height: f64, y: f64, s: f64, mass: f64) {
    // cumulative weight of the tent centred at y below height u
    let cdf = |u: f64| {
        let t = ((u - y) / s).clamp(-1.0, 1.0);
        if t < 0.0 {
            0.5 * (1.0 + t) * (1.0 + t)
        } else {
            1.0 - 0.5 * (1.0 - t) * (1.0 - t)
        }
    };
    let inside = cdf(height) - cdf(0.0);
    let dz = height / layers.len() as f64;
    if inside <= 0.0 {
        let k = ((y.clamp(0.0, height) / dz) as usize).min(layers.len() - 1);
        layers[k] += mass;
        return;
    }
    let lo = ((y - s).max(0.0) / dz) as usize;
    let hi = (((y + s).min(height) / dz) as usize).min(layers.len() - 1);
    for (k, layer) in layers.iter_mut().enumerate().take(hi + 1).skip(lo) {
        let w = cdf((k + 1) as f64 * dz) - cdf(k as f64 * dz);
        *layer += mass * w / inside;
    }
}

/// Mass of each layer now over its initial mass (`initial_layer_mass`); layers with no initial
/// mass are left out.
pub fn layer_mass_ratios(state: &ParticleState, cfg: &ShotConfig, initial: &[f64]) -> Vec<f64> {
    let mut layers = vec![0.0; MASS_LAYERS];
    for (p, info) in state.pos.iter().zip(&state.info) {
        let spacing = levels::radius(cfg.domain.spacing, info[1]);
        spread_over_layers(
            &mut layers,
            cfg.domain.size[1],
            p[1] as f64,
            spacing,
            levels::mass(1.0, info[1]),
        );
    }
    layers
        .iter()
        .zip(initial)
        .filter(|(_, &m0)| m0 > 0.0)
        .map(|(&m, &m0)| m / m0)
        .collect()
}

/// Height below which `q` of the cloud mass lies (mass-weighted quantile of y; `pts` is
/// (y, cloud mass), sorted here).
fn cloud_quantile(pts: &mut [(f64, f64)], total: f64, q: f64) -> f64 {
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut acc = 0.0;
    for &(y, m) in pts.iter() {
        acc += m;
        if acc >= q * total {
            return y;
        }
    }
    pts.last().map_or(0.0, |p| p.0)
}

/// Diagnostics of the air itself, so that a failing atmosphere shows in stats.jsonl without
/// reading VDBs (docs/PHYSICS.md "Diagnostics"). Keys:
/// - `layer_mass_ratio_min`, `layer_mass_ratio_max`: over [`MASS_LAYERS`] equal horizontal
///   layers, mass now / initial mass (1 in a box that neither drains nor piles up);
/// - `cloud_ceiling_fraction`: cloud mass within one level-0 kernel radius h0 of the ceiling,
///   as a fraction of all cloud mass; `cloud_top10_fraction`: in the top 10% of the height;
///   `cloud_face_fraction`: within h0 of a periodic face (x or z);
/// - `cloud_base`, `cloud_top` (m): heights below which 1% and 99% of the cloud mass lie (0
///   without cloud);
/// - `static_energy_mean` (K): mass-weighted mean of the liquid-water static temperature
///   T + Gamma_d y - Q w, which only heating and mixing with the walls change: its rise from
///   one frame to the next is the heat that stayed in the air;
/// - `heat_input_mean` (K): the mass-weighted mean heating of this frame, estimated as the
///   heating rate of eq. 5 (with the sources) at the frame-end state times frame_seconds;
/// - `water_input` (kg): the vapor a moist ground (`physics.bowen_ratio`) evaporated and the
///   vapor sources added this frame, estimated the same way (0 over a dry ground without vapor
///   sources): the expected rise of `total_water`;
/// - `clamped_particles`: particles at the speed clamp (|v| >= 0.999 solver.max_speed).
pub fn atmosphere_diagnostics(
    state: &ParticleState,
    cfg: &ShotConfig,
    initial_layers: &[f64],
    time: f64,
    maps: &crate::sim::sources::HeatMaps,
) -> AtmosphereDiagnostics {
    let p = &cfg.physics;
    let size = cfg.domain.size;
    let h0 = cfg.domain.kernel_radius();
    let periodic = [
        cfg.domain.periodic.contains(&crate::config::Axis::X),
        cfg.domain.periodic.contains(&crate::config::Axis::Z),
    ];
    let heat = crate::sim::thermo::ThermoParams::new(cfg, 1.0, time).with_maps(maps);
    let max_speed = cfg.solver.max_speed;
    let (mut cloud, mut ceiling, mut top10, mut face) = (0.0, 0.0, 0.0, 0.0);
    let (mut mass, mut energy, mut heating, mut moisture) = (0.0, 0.0, 0.0, 0.0);
    let mut clamped = 0usize;
    let mut cloud_pts = Vec::new();
    for i in 0..state.len() {
        let m = levels::mass(1.0, state.info[i][1]);
        let q = Vec4::from(state.pos[i]).truncate().as_dvec3();
        let th = state.thermo[i].map(|v| v as f64);
        let v = Vec4::from(state.vel[i]).truncate().as_dvec3();
        mass += m;
        energy += m * (th[0] + p.adiabatic_lapse_rate * q[1] - p.latent_heat * th[2]);
        let [rate, vapor] =
            crate::sim::source_field::source_rates(&heat, &maps.values, q.to_array());
        heating += m * rate;
        moisture += m * vapor;
        if v.length() >= 0.999 * max_speed {
            clamped += 1;
        }
        let w = m * th[2];
        if w > 0.0 {
            cloud += w;
            cloud_pts.push((q[1], w));
            if q[1] > size[1] - h0 {
                ceiling += w;
            }
            if q[1] > 0.9 * size[1] {
                top10 += w;
            }
            let near = |a: usize| q[a] < h0 || q[a] > size[a] - h0;
            if (periodic[0] && near(0)) || (periodic[1] && near(2)) {
                face += w;
            }
        }
    }
    let ratios = layer_mass_ratios(state, cfg, initial_layers);
    let frac = |x: f64| if cloud > 0.0 { x / cloud } else { 0.0 };
    let min = ratios.iter().copied().fold(f64::INFINITY, f64::min);
    let max = ratios.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (cloud_base, cloud_top) = if cloud > 0.0 {
        (
            cloud_quantile(&mut cloud_pts, cloud, 0.01),
            cloud_quantile(&mut cloud_pts, cloud, 0.99),
        )
    } else {
        (0.0, 0.0)
    };
    let mean = |x: f64| if mass > 0.0 { x / mass } else { 0.0 };
    AtmosphereDiagnostics {
        layer_mass_ratio_min: if ratios.is_empty() { 1.0 } else { min },
        layer_mass_ratio_max: if ratios.is_empty() { 1.0 } else { max },
        cloud_ceiling_fraction: frac(ceiling),
        cloud_top10_fraction: frac(top10),
        cloud_face_fraction: frac(face),
        cloud_base,
        cloud_top,
        static_energy_mean: mean(energy),
        heat_input_mean: mean(heating) * cfg.output.frame_seconds,
        water_input: (heating * heat.ground_vapor as f64 + moisture)
            * cfg.cell_mass()
            * cfg.output.frame_seconds,
        clamped_particles: clamped as u64,
    }
}

/// The atmosphere's figures of a frame ([`atmosphere_diagnostics`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AtmosphereDiagnostics {
    pub layer_mass_ratio_min: f64,
    pub layer_mass_ratio_max: f64,
    pub cloud_ceiling_fraction: f64,
    pub cloud_top10_fraction: f64,
    pub cloud_face_fraction: f64,
    pub cloud_base: f64,
    pub cloud_top: f64,
    pub static_energy_mean: f64,
    pub heat_input_mean: f64,
    pub water_input: f64,
    pub clamped_particles: u64,
}

impl AtmosphereDiagnostics {
    /// Adds the figures under their stats.jsonl names.
    pub fn insert_into(&self, out: &mut BTreeMap<String, f64>) {
        for (k, v) in [
            ("layer_mass_ratio_min", self.layer_mass_ratio_min),
            ("layer_mass_ratio_max", self.layer_mass_ratio_max),
            ("cloud_ceiling_fraction", self.cloud_ceiling_fraction),
            ("cloud_top10_fraction", self.cloud_top10_fraction),
            ("cloud_face_fraction", self.cloud_face_fraction),
            ("cloud_base", self.cloud_base),
            ("cloud_top", self.cloud_top),
            ("static_energy_mean", self.static_energy_mean),
            ("heat_input_mean", self.heat_input_mean),
            ("water_input", self.water_input),
            ("clamped_particles", self.clamped_particles as f64),
        ] {
            out.insert(k.to_string(), v);
        }
    }
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
        let m0 = cfg.cell_mass();
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
        assert_eq!(d.cloudy_particles, 10);
        let cloud = m0 * (9.0 * 1e-3 + 2e-3);
        assert!(
            (d.cloud_mass - cloud).abs() < 1e-6 * cloud,
            "w is stored in f32"
        );
        let water = m0 * (10.0 * 0.01 + 9.0 * 1e-3 + 2e-3) + 0.5 * m0 * 0.01;
        assert!((d.total_water - water).abs() < 1e-6 * water);
        assert!((d.isolation - 2e-3 / (9.0 * 1e-3 + 2e-3)).abs() < 1e-6);
        assert_eq!(d.temperature_max, 300.0);
        let tmean = (9.0 * 290.0 + 280.0 + 0.5 * 300.0) / 10.5;
        assert!((d.temperature_mean - tmean).abs() < 1e-4);
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
        assert_eq!(d.isolation, 0.0);
        let empty = cloud_diagnostics(&state(&[]), &cfg);
        assert_eq!(empty.isolation, 0.0);
        assert_eq!(empty.cloud_mass, 0.0);
    }
}
