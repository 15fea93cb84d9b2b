//! f64 mirror of shaders/adaptive_merge.wgsl: `adaptive_merge`, one colour pass. The shader
//! shares each slot's neighbourhood scans across a workgroup and reduces to the nearest partner
//! (ties: the first in neighbourhood order); walking the slots one by one, as here, gives the
//! same merges.
use super::adaptive::RefParticles;
use super::common::{grid_min_image, level_radius, wrap_pos};
use super::grid::for_each_slot;
use crate::sim::adaptive::{AdaptiveParams, ColourPass, FLAG_DEAD, FLAG_MERGE, FLAG_MERGED};
use crate::sim::grid_params::GridParams;

/// One colour pass of the merge; its cells are independent, so running them one after another
/// gives what the parallel workgroups give.
pub fn adaptive_merge(
    g: &GridParams,
    prm: &AdaptiveParams,
    colour: &ColourPass,
    cell_start: &[u32],
    p: &mut RefParticles,
    flags: &mut [u32],
) {
    let h0 = prm.h0 as f64;
    for t in 0..colour.cells() {
        let c = colour.cell(t);
        let cell = g
            .neighbor_cell(c, [0, 0, 0])
            .expect("colour cells are inside") as usize;
        for i in g.cell_slots(cell_start, cell as u32) {
            let i = i as usize;
            if flags[i] != FLAG_MERGE {
                continue;
            }
            let level = p.info[i][1];
            let xi = p.xyz(i);
            let h = level_radius(h0, level);
            let (mut best, mut best_d2) = (None, h * h);
            for_each_slot(g, cell_start, c, |k| {
                if k != i && flags[k] == FLAG_MERGE && p.info[k][1] == level {
                    let d = grid_min_image(p.xyz(k) - xi, g);
                    if d.dot(d) < best_d2 {
                        best_d2 = d.dot(d);
                        best = Some(k);
                    }
                }
                true
            });
            let Some(j) = best else { continue };
            let dj = grid_min_image(p.xyz(j) - xi, g);
            let m = wrap_pos(xi + 0.5 * dj, g);
            let r = prm.min_distance as f64 * level_radius(h0, level - 1);
            let mut clear = true;
            for_each_slot(g, cell_start, c, |k| {
                if k != i && k != j && flags[k] & FLAG_DEAD == 0 {
                    let d = grid_min_image(m - p.xyz(k), g);
                    if d.dot(d) < r * r {
                        clear = false;
                    }
                }
                clear
            });
            if !clear {
                continue;
            }
            p.pos[i] = m.extend(p.pos[i][3]).to_array();
            p.vel[i] = std::array::from_fn(|a| 0.5 * (p.vel[i][a] + p.vel[j][a]));
            p.thermo[i] = std::array::from_fn(|a| 0.5 * (p.thermo[i][a] + p.thermo[j][a]));
            p.info[i] = [p.info[i][0].min(p.info[j][0]), level - 1];
            flags[i] = FLAG_MERGED;
            flags[j] = FLAG_DEAD;
        }
    }
}
