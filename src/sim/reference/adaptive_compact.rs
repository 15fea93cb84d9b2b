//! f64 mirror of shaders/adaptive_compact.wgsl (`compact_holes`, `compact_move`): the in-place
//! removal of merged-away particles.
use super::adaptive::{Counters, RefParticles};
use crate::sim::adaptive::{AdaptiveParams, FLAG_DEAD};

pub fn compact_holes(
    prm: &AdaptiveParams,
    c: &Counters,
    scan: &[u32],
    flags: &[u32],
    holes: &mut [u32],
) {
    for i in 0..prm.count as usize {
        if i < c.newcount as usize && flags[i] & FLAG_DEAD != 0 {
            holes[scan[i] as usize] = i as u32;
        }
    }
}

pub fn compact_move(
    prm: &AdaptiveParams,
    c: &Counters,
    scan: &[u32],
    flags: &mut [u32],
    holes: &[u32],
    p: &mut RefParticles,
) {
    let nc = c.newcount as usize;
    for j in nc..prm.count as usize {
        let f = flags[j];
        if f & FLAG_DEAD == 0 {
            let rank = (j - nc) - (scan[j] - scan[nc]) as usize;
            let dst = holes[rank] as usize;
            p.pos[dst] = p.pos[j];
            p.vel[dst] = p.vel[j];
            p.thermo[dst] = p.thermo[j];
            p.info[dst] = p.info[j];
            flags[dst] = f;
        }
        flags[j] = 0;
    }
}
