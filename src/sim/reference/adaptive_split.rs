//! f64 mirror of shaders/adaptive_split.wgsl (`adaptive_split`), with its count per level.
use super::adaptive::{Counters, RefParticles};
use super::common::children;
use crate::ground::levels::MAX_LEVEL;
use crate::sim::adaptive::{AdaptiveParams, FLAG_SPLIT};
use crate::sim::grid_params::GridParams;

/// Splits the marked particles below `newcount` whose rank fits the free capacity, and counts
/// every final particle's level into `c.levels` (zeroed by `totals_split`).
pub fn adaptive_split(
    g: &GridParams,
    prm: &AdaptiveParams,
    c: &mut Counters,
    scan: &[u32],
    flags: &[u32],
    p: &mut RefParticles,
) {
    let bin = |level: u32| level.min(MAX_LEVEL) as usize;
    for i in 0..c.newcount as usize {
        if flags[i] & FLAG_SPLIT == 0 || scan[i] >= c.splits {
            c.levels[bin(p.info[i][1])] += 1;
            continue;
        }
        c.levels[bin(p.info[i][1] + 1)] += 2;
        let k = scan[i];
        let slot = (c.newcount + k) as usize;
        let [id, level] = p.info[i];
        let [a, b] = children(
            g,
            prm.h0 as f64,
            prm.split_offset as f64,
            p.xyz(i),
            id,
            level,
        );
        let w = p.pos[i][3];
        p.pos[i] = a.extend(w).to_array();
        p.pos[slot] = b.extend(w).to_array();
        p.vel[slot] = p.vel[i];
        p.thermo[slot] = p.thermo[i];
        p.info[i] = [id, level + 1];
        p.info[slot] = [prm.next_id + k, level + 1];
    }
}
