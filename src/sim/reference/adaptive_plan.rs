//! Mirror of shaders/adaptive_plan.wgsl: `merge_cells`, the cells of each colour the merge
//! visits (those holding a merge-marked particle with a merge-marked partner in reach, `may_merge`;
//! the GPU lists them in any order, so the
//! mirror gives them ascending) and each one's loop estimate against the device's budget, and
//! `merge_dispatch`, a workgroup per listed cell.
use super::common::{grid_min_image, level_radius};
use super::grid::for_each_slot;
use crate::sim::adaptive::{ColourMap, FLAG_MERGE};
use crate::sim::grid_params::GridParams;
use glam::DVec3;

/// What `merge_cells` finds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MergeCells {
    /// Per colour, the cells with a merge-marked particle, ascending.
    pub cells: Vec<Vec<u32>>,
    /// The largest loop estimate of one merge invocation (0 without marks).
    pub max_estimate: u32,
    /// Some listed cell's estimate is over the budget (the frame's error).
    pub over_budget: bool,
}

/// The particles as `merge_cells` reads them (cell-ordered).
#[derive(Debug, Clone, Copy)]
pub struct Marks<'a> {
    pub flags: &'a [u32],
    pub level: &'a [u32],
    pub pos: &'a [[f64; 3]],
    /// Program radius of level 0.
    pub h0: f64,
}

/// Loop trips of `may_merge` before it lists a cell unchecked (`PARTNER_SCAN_CAP`).
pub const PARTNER_SCAN_CAP: u32 = 8192;

/// Mirror of `may_merge`: whether a merge-marked slot of cell `c` has a merge-marked partner on
/// its level closer than h (adaptive_merge's partner test), or the scan passed the cap.
fn may_merge(g: &GridParams, cell_start: &[u32], m: &Marks, cell: u32, c: [i32; 3]) -> bool {
    let own = g.cell_slots(cell_start, cell);
    let mut tested = 0u32;
    let mut found = false;
    for_each_slot(g, cell_start, c, |k| {
        tested += 1;
        if tested > PARTNER_SCAN_CAP {
            found = true;
            return false;
        }
        if m.flags[k] != FLAG_MERGE {
            return true;
        }
        let lk = m.level[k];
        let h = level_radius(m.h0, lk);
        for i in own.clone().map(|i| i as usize) {
            tested += 1;
            if tested > PARTNER_SCAN_CAP {
                found = true;
                return false;
            }
            if i == k || m.flags[i] != FLAG_MERGE || m.level[i] != lk {
                continue;
            }
            let d = grid_min_image(DVec3::from(m.pos[k]) - DVec3::from(m.pos[i]), g);
            if d.dot(d) < h * h {
                found = true;
                return false;
            }
        }
        true
    });
    found
}

/// Mirror of `merge_cells` for workgroups of `wg` threads and a loop budget of `budget`.
pub fn merge_cells(
    g: &GridParams,
    cell_start: &[u32],
    m: &Marks,
    wg: u32,
    budget: u32,
) -> MergeCells {
    let flags = m.flags;
    let map = ColourMap::of(g);
    let colours = (map.classes[0] * map.classes[1] * map.classes[2]) as usize;
    let mut out = MergeCells {
        cells: vec![Vec::new(); colours],
        max_estimate: 0,
        over_budget: false,
    };
    let [dx, dy, _] = g.dims;
    for c in 0..g.num_cells {
        let own = g.cell_slots(cell_start, c);
        let marked = own
            .clone()
            .filter(|&k| flags[k as usize] == FLAG_MERGE)
            .count() as u32;
        if marked == 0 {
            continue;
        }
        let cc = [c % dx, (c / dx) % dy, c / (dx * dy)];
        if !may_merge(g, cell_start, m, c, cc.map(|v| v as i32)) {
            continue;
        }
        let mut nb = 0u32;
        for_each_slot(g, cell_start, cc.map(|v| v as i32), |_| {
            nb += 1;
            true
        });
        let share = nb / wg + 1;
        let estimate = own.len() as u32 + marked * (2 * (27 + share) + 16);
        out.max_estimate = out.max_estimate.max(estimate);
        out.over_budget |= estimate > budget;
        out.cells[map.colour(cc) as usize].push(c);
    }
    out
}

/// Mirror of `merge_dispatch`: (x, y, z, 0) workgroups per colour, one per listed cell.
pub fn merge_dispatch(cells: &MergeCells, max_groups_x: u32) -> Vec<[u32; 4]> {
    cells
        .cells
        .iter()
        .map(|list| {
            let [x, y, z] = crate::gpu::program::groups_for(list.len() as u32, 1, max_groups_x);
            [x, y, z, 0]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::adaptive::FLAG_MERGED;
    use crate::sim::reference::grid::build_cell_table;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};

    /// Against a brute-force count over the particles' own cells, on a grid periodic in x
    /// (the wrap) and walled in z, with one crowded cell.
    #[test]
    fn merge_cells_matches_a_brute_force_count() {
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
        let level: Vec<u32> = (0..sorted.len()).map(|_| rng.random_range(1..=2)).collect();
        let h0 = 0.1;
        // a merge-marked partner on i's level closer than h (any cell: h <= h0 = the cell size)
        let partnered = |i: usize| {
            let h = level_radius(h0, level[i]);
            (0..sorted.len()).any(|k| {
                let d = grid_min_image(DVec3::from(sorted[k]) - DVec3::from(sorted[i]), &g);
                k != i && flags[k] == FLAG_MERGE && level[k] == level[i] && d.dot(d) < h * h
            })
        };
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
        let map = ColourMap::of(&g);
        let mut listed = vec![Vec::new(); 27 * 2];
        let (mut max_estimate, mut crowded, mut unpartnered) = (0u32, 0usize, 0);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let c = [x, y, z];
                    let own = (0..sorted.len()).filter(|&k| cells[k] == c);
                    let marked = own.clone().filter(|&k| flags[k] == FLAG_MERGE).count() as u32;
                    let nb = cells.iter().filter(|&&q| near(c, q)).count() as u32;
                    let occupancy = own.clone().count() as u32;
                    crowded = crowded.max(occupancy as usize);
                    let pairs = own.clone().any(|k| flags[k] == FLAG_MERGE && partnered(k));
                    unpartnered += (marked > 0 && !pairs) as u32;
                    if pairs {
                        let estimate = occupancy + marked * (2 * (27 + nb / 64 + 1) + 16);
                        max_estimate = max_estimate.max(estimate);
                        let cu = c.map(|v| v as u32);
                        let index = (z * dims[1] + y) * dims[0] + x;
                        listed[map.colour(cu) as usize].push(index as u32);
                    }
                }
            }
        }
        assert!(crowded >= 40, "the crowded cell: {crowded}");
        let listed_cells: usize = listed.iter().map(Vec::len).sum();
        assert!(
            unpartnered >= 5 && listed_cells > 10,
            "cells with marks but no partner {unpartnered}, listed {listed_cells}"
        );
        let marks = Marks {
            flags: &flags,
            level: &level,
            pos: &sorted,
            h0,
        };
        let got = merge_cells(&g, &cell_start, &marks, 64, 60_000);
        listed.truncate(got.cells.len());
        assert_eq!(got.cells, listed);
        assert_eq!(got.max_estimate, max_estimate);
        assert!(!got.over_budget);
        assert!(merge_cells(&g, &cell_start, &marks, 64, max_estimate - 1).over_budget);
        let args = merge_dispatch(&got, 65535);
        for (a, list) in args.iter().zip(&got.cells) {
            assert_eq!(a[0] as usize * a[1] as usize, list.len().max(a[0] as usize));
        }
    }

    /// A lone merge-marked particle without a partner is listed only when its neighbourhood is
    /// so crowded that the partner scan passes its cap (the merge then finds nothing itself).
    #[test]
    fn a_crowded_neighbourhood_is_listed_unchecked() {
        let g = GridParams::new([0.5, 0.5, 0.5], 0.1, true, true);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let lone = [0.25, 0.25, 0.25];
        let listed = |crowd: usize, rng: &mut rand_chacha::ChaCha8Rng| {
            let mut pos = vec![lone];
            // unmarked particles in the cells around the lone one's (not its own)
            while pos.len() < crowd + 1 {
                let p = DVec3::new(rng.random(), rng.random(), rng.random()) * 0.3 + 0.1;
                if g.cell_coord(p) != g.cell_coord(lone.into()) {
                    pos.push(p.to_array());
                }
            }
            let (order, cell_start) = build_cell_table(&g, &pos);
            let sorted: Vec<[f64; 3]> = order.iter().map(|&o| pos[o as usize]).collect();
            let flags: Vec<u32> = order
                .iter()
                .map(|&o| (o == 0) as u32 * FLAG_MERGE)
                .collect();
            let level = vec![1; sorted.len()];
            let marks = Marks {
                flags: &flags,
                level: &level,
                pos: &sorted,
                h0: 0.1,
            };
            let got = merge_cells(&g, &cell_start, &marks, 64, u32::MAX);
            got.cells.iter().map(Vec::len).sum::<usize>()
        };
        assert_eq!(listed(500, &mut rng), 0);
        assert_eq!(listed(PARTNER_SCAN_CAP as usize + 10, &mut rng), 1);
    }
}
