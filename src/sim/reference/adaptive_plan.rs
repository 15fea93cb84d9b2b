//! Mirror of shaders/adaptive_plan.wgsl: `merge_cells`, the cells of each colour the merge
//! visits (those holding a merge-marked particle; the GPU lists them in any order, so the
//! mirror gives them ascending) and each one's loop estimate against the device's budget, and
//! `merge_dispatch`, a workgroup per listed cell.
use super::grid::for_each_slot;
use crate::sim::adaptive::{ColourMap, FLAG_MERGE};
use crate::sim::grid_params::GridParams;

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

/// Mirror of `merge_cells` for workgroups of `wg` threads and a loop budget of `budget`.
pub fn merge_cells(
    g: &GridParams,
    cell_start: &[u32],
    flags: &[u32],
    wg: u32,
    budget: u32,
) -> MergeCells {
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
            let [x, y, z] = crate::gpu::stage::groups_for(list.len() as u32, 1, max_groups_x);
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
        let (mut max_estimate, mut crowded) = (0u32, 0usize);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let c = [x, y, z];
                    let own = (0..sorted.len()).filter(|&k| cells[k] == c);
                    let marked = own.clone().filter(|&k| flags[k] == FLAG_MERGE).count() as u32;
                    let nb = cells.iter().filter(|&&q| near(c, q)).count() as u32;
                    let occupancy = own.count() as u32;
                    crowded = crowded.max(occupancy as usize);
                    if marked > 0 {
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
        let got = merge_cells(&g, &cell_start, &flags, 64, 60_000);
        listed.truncate(got.cells.len());
        assert_eq!(got.cells, listed);
        assert_eq!(got.max_estimate, max_estimate);
        assert!(!got.over_budget);
        assert!(merge_cells(&g, &cell_start, &flags, 64, max_estimate - 1).over_budget);
        let args = merge_dispatch(&got, 65535);
        for (a, list) in args.iter().zip(&got.cells) {
            assert_eq!(a[0] as usize * a[1] as usize, list.len().max(a[0] as usize));
        }
    }
}
