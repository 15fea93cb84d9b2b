//! f64 mirror of shaders/adaptive_merge.wgsl: `adaptive_merge` (one colour pass) and
//! `cell_load` (what the host sizes the merge rounds from, `sim::adaptive::merge_rounds`).
use super::adaptive::RefParticles;
use super::common::{grid_min_image, level_radius, wrap_pos};
use super::grid::for_each_slot;
use crate::sim::adaptive::{AdaptiveParams, ColourPass, FLAG_DEAD, FLAG_MERGE, FLAG_MERGED};
use crate::sim::grid_params::GridParams;

/// One colour pass of the merge; its cells are independent, so running them one after another
/// gives what the parallel threads give, and one pass over a cell what its rounds give.
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

/// Mirror of `cell_load`: the largest cell occupancy, the largest 27-cell neighbourhood and the
/// most merge-marked particles in one cell, over all cells (the `load` buffer's first three).
pub fn cell_load(g: &GridParams, cell_start: &[u32], flags: &[u32]) -> [u32; 3] {
    let [dx, dy, _] = g.dims;
    let mut load = [0u32; 3];
    for c in 0..g.num_cells {
        let cc = [c % dx, (c / dx) % dy, c / (dx * dy)].map(|v| v as i32);
        let mut nb = 0;
        for_each_slot(g, cell_start, cc, |_| {
            nb += 1;
            true
        });
        let own = g.cell_slots(cell_start, c);
        let marked = own
            .clone()
            .filter(|&k| flags[k as usize] == FLAG_MERGE)
            .count() as u32;
        load[0] = load[0].max(own.len() as u32);
        load[1] = load[1].max(nb);
        load[2] = load[2].max(marked);
    }
    load
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::reference::grid::build_cell_table;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};

    /// Against a brute-force count over the particles' own cells, on a grid periodic in x
    /// (the wrap) and walled in z, with one crowded cell.
    #[test]
    fn cell_load_matches_a_brute_force_count() {
        let g = GridParams::new([0.6, 0.4, 0.5], 0.1, true, false);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut unit = || DVec3::new(rng.random(), rng.random(), rng.random());
        let mut pos: Vec<[f64; 3]> = (0..700)
            .map(|_| (unit() * DVec3::new(0.6, 0.4, 0.5)).to_array())
            .collect();
        // the crowded cell, at the periodic x face
        pos.extend((0..40).map(|_| (DVec3::new(0.55, 0.01, 0.25) + 0.04 * unit()).to_array()));
        let (order, cell_start) = build_cell_table(&g, &pos);
        let sorted: Vec<[f64; 3]> = order.iter().map(|&o| pos[o as usize]).collect();
        let flags: Vec<u32> = (0..sorted.len())
            .map(|_| [0, FLAG_MERGE, FLAG_MERGE, 2, FLAG_MERGED][rng.random_range(0..5)])
            .collect();
        let cells: Vec<[i32; 3]> = sorted.iter().map(|&p| g.cell_coord(p.into())).collect();
        let dims = g.dims.map(|d| d as i32);
        let near = |a: [i32; 3], b: [i32; 3]| {
            (0..3).all(|k| {
                let d = (a[k] - b[k]).rem_euclid(dims[k]);
                let wraps = (k == 0 && g.periodic_x()) || (k == 2 && g.periodic_z());
                if wraps {
                    d <= 1 || d == dims[k] - 1
                } else {
                    (a[k] - b[k]).abs() <= 1
                }
            })
        };
        let mut expect = [0u32; 3];
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let c = [x, y, z];
                    let own = (0..sorted.len()).filter(|&k| cells[k] == c);
                    let marked = own.clone().filter(|&k| flags[k] == FLAG_MERGE).count();
                    let nb = cells.iter().filter(|&&q| near(c, q)).count();
                    expect[0] = expect[0].max(own.count() as u32);
                    expect[1] = expect[1].max(nb as u32);
                    expect[2] = expect[2].max(marked as u32);
                }
            }
        }
        assert!(expect[0] >= 40, "the crowded cell: {expect:?}");
        assert_eq!(cell_load(&g, &cell_start, &flags), expect);
    }
}
