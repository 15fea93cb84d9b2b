//! f64 mirror of shaders/adaptive_stats.wgsl (`totals_merge`, `totals_split`, `count_levels`):
//! the counters after the scans and the particles per level.
use super::adaptive::{Counters, RefParticles};
use crate::sim::adaptive::{AdaptiveParams, FLAG_DEAD, FLAG_SPLIT, MAX_LEVELS};

/// Total of an exclusive scan over the first n flags for the given bit.
fn scan_total(scan: &[u32], flags: &[u32], n: usize, bit: u32) -> u32 {
    if n == 0 {
        0
    } else {
        scan[n - 1] + (flags[n - 1] & bit != 0) as u32
    }
}

pub fn totals_merge(prm: &AdaptiveParams, scan: &[u32], flags: &[u32], c: &mut Counters) {
    let dead = scan_total(scan, flags, prm.count as usize, FLAG_DEAD);
    c.merges = dead;
    c.newcount = prm.count - dead;
}

pub fn totals_split(prm: &AdaptiveParams, scan: &[u32], flags: &[u32], c: &mut Counters) {
    let wanted = scan_total(scan, flags, prm.count as usize, FLAG_SPLIT);
    let done = wanted.min(prm.capacity - c.newcount);
    c.split_wanted = wanted;
    c.splits = done;
    c.skipped = wanted - done;
    c.final_count = c.newcount + done;
    c.next_id = prm.next_id + done;
    c.levels = vec![0; MAX_LEVELS as usize];
}

pub fn count_levels(c: &mut Counters, p: &RefParticles) {
    for i in 0..c.final_count as usize {
        c.levels[(p.info[i][1]).min(MAX_LEVELS - 1) as usize] += 1;
    }
}
