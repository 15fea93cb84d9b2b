//! f64 mirror of a whole adaptive run as `sim::adaptive::AdaptiveStage` encodes it: the
//! particle arrays and counters of the stage and [`run`], which calls the entry points of
//! shaders/adaptive_*.wgsl (mirrored file for file: `adaptive_mark`, `adaptive_merge`,
//! `adaptive_compact`, `adaptive_split`, `adaptive_stats`, with the scan of `scan`) in the GPU's
//! order. Arrays have the GPU's length (`capacity`) so slot assignment (compaction, appended
//! children) mirrors the GPU exactly.
use super::adaptive_compact::{compact_holes, compact_move};
use super::adaptive_mark::adaptive_mark;
use super::adaptive_merge::adaptive_merge;
use super::adaptive_split::adaptive_split;
use super::adaptive_stats::{totals_merge, totals_split};
use super::scan::exclusive_scan;
use crate::sim::adaptive::{
    colour_passes, mass_units, AdaptiveParams, AdaptiveReport, FLAG_DEAD, FLAG_SPLIT,
};
use crate::sim::grid_params::GridParams;
use glam::{DVec3, DVec4};

/// Particle arrays of length `capacity` (xyzw as on the GPU; pos.w is carried, unused).
#[derive(Debug, Clone, PartialEq)]
pub struct RefParticles {
    pub pos: Vec<[f64; 4]>,
    pub vel: Vec<[f64; 4]>,
    pub thermo: Vec<[f64; 4]>,
    pub info: Vec<[u32; 2]>,
}

impl RefParticles {
    /// The first `pos.len()` particles live, padded with zeros to `capacity`.
    pub fn from_f32(
        pos: &[[f32; 4]],
        vel: &[[f32; 4]],
        thermo: &[[f32; 4]],
        info: &[[u32; 2]],
        capacity: usize,
    ) -> Self {
        let widen = |v: &[[f32; 4]]| {
            let mut out: Vec<[f64; 4]> = v.iter().map(|a| a.map(|x| x as f64)).collect();
            out.resize(capacity, [0.0; 4]);
            out
        };
        let mut info = info.to_vec();
        info.resize(capacity, [0, 0]);
        Self {
            pos: widen(pos),
            vel: widen(vel),
            thermo: widen(thermo),
            info,
        }
    }

    /// Position of slot i.
    pub fn xyz(&self, i: usize) -> DVec3 {
        DVec4::from(self.pos[i]).truncate()
    }
}

/// Mirror of the counters buffer.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Counters {
    pub merges: u32,
    pub newcount: u32,
    pub split_wanted: u32,
    pub splits: u32,
    pub skipped: u32,
    pub final_count: u32,
    pub next_id: u32,
    pub levels: Vec<u32>,
}

/// The whole stage, in the GPU's order; `prm.count` and `prm.next_id` describe the input.
pub fn run(
    g: &GridParams,
    prm: &AdaptiveParams,
    cell_start: &[u32],
    p: &mut RefParticles,
) -> AdaptiveReport {
    let cap = prm.capacity as usize;
    let n = prm.count as usize;
    let mut flags = vec![0u32; cap];
    let mut holes = vec![0u32; cap];
    let mut c = Counters::default();
    adaptive_mark(g, prm, cell_start, p, &mut flags);
    for colour in colour_passes(g) {
        adaptive_merge(g, prm, &colour, cell_start, p, &mut flags);
    }
    let scan = exclusive_scan(&flags, n, FLAG_DEAD);
    totals_merge(prm, &scan, &flags, &mut c);
    compact_holes(prm, &c, &scan, &flags, &mut holes);
    compact_move(prm, &c, &scan, &mut flags, &holes, p);
    let scan = exclusive_scan(&flags, n, FLAG_SPLIT);
    totals_split(prm, &scan, &flags, &mut c);
    adaptive_split(g, prm, &mut c, &scan, &flags, p);
    let per_level = c.levels[..prm.max_level as usize + 1].to_vec();
    AdaptiveReport {
        mass_units: mass_units(&per_level, prm.max_level),
        per_level,
        splits: c.splits,
        merges: c.merges,
        skipped_splits: c.skipped,
        count: c.final_count,
        next_id: c.next_id,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::AdaptiveConfig;
    use crate::sim::reference::grid::build_cell_table;
    use rand::{Rng, SeedableRng};

    /// Random particles; merges and splits happen and mass units are conserved by the mirror.
    #[test]
    fn mirror_conserves_mass_units_and_ids() {
        let g = GridParams::new([1.0, 0.65, 1.1], 0.1, true, true);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 1500;
        let pos: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                [
                    rng.random::<f64>(),
                    0.05 + 0.55 * rng.random::<f64>(),
                    1.1 * rng.random::<f64>(),
                ]
            })
            .collect();
        let (order, cell_start) = build_cell_table(&g, &pos);
        let mut p = RefParticles::from_f32(&[], &[], &[], &[], 2 * n);
        for (k, &o) in order.iter().enumerate() {
            p.pos[k] = DVec3::from(pos[o as usize]).extend(0.0).to_array();
            p.thermo[k] = [
                280.0,
                0.01,
                if rng.random::<bool>() { 0.0 } else { 0.01 },
                0.0,
            ];
            p.info[k] = [o, rng.random_range(0..=3)];
        }
        let cfg = AdaptiveConfig::default();
        let mut prm = AdaptiveParams::new(&cfg, 0.1, 2 * n as u32);
        prm.count = n as u32;
        prm.next_id = n as u32;
        let before: u64 = p.info[..n]
            .iter()
            .map(|i| crate::sim::adaptive::level_mass_units(i[1], 3))
            .sum();
        let rep = run(&g, &prm, &cell_start, &mut p);
        assert!(rep.merges > 10 && rep.splits > 10, "{rep:?}");
        assert_eq!(rep.mass_units, before);
        let mut ids: Vec<u32> = p.info[..rep.count as usize].iter().map(|i| i[0]).collect();
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), rep.count as usize);
    }
}
