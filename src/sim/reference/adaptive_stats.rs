//! f64 mirror of shaders/adaptive_stats.wgsl (`totals_merge`, `totals_split`):
//! the counters after the scans (adaptive_split counts the particles per level).
use super::adaptive::Counters;
use crate::ground::levels::MAX_LEVEL;
use crate::sim::adaptive::{AdaptiveParams, FLAG_DEAD, FLAG_SPLIT};

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
    c.levels = vec![0; MAX_LEVEL as usize + 1];
}
