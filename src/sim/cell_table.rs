//! The neighbour table on the host, in f64: the (cell, x slice) keys, the counting sort into a
//! cell table and the 27-cell neighbour walks. The diagnostics and the boundary setup use it;
//! it is also the f64 mirror of shaders/grid.wgsl (`cell_keys`, `cell_scatter` and
//! `cell_order`), re-exported as `reference::grid`, and the walk of the other mirrors.
//!
//! As in every mirror, arrays of particles are `[f64; 3]`/`[f64; 4]` like the GPU's storage
//! buffers, and the maths on one particle is `DVec3`, loaded from and stored to them.
use crate::sim::grid_params::GridParams;
use crate::sim::kernels::{domain_size, min_image};
use glam::DVec3;

/// Mirror of `cell_keys`: the (cell, x slice) key of each position, and the count of each key
/// at entry key + 1 (`GridParams::table_len` entries).
pub fn cell_keys(grid: &GridParams, pos: &[[f64; 3]]) -> (Vec<u32>, Vec<u32>) {
    let keys: Vec<u32> = pos.iter().map(|&p| grid.slice_key(p.into())).collect();
    let mut counts = vec![0u32; grid.table_len()];
    for &k in &keys {
        counts[k as usize + 1] += 1;
    }
    (keys, counts)
}

/// Mirror of `cell_scatter` followed by `cell_order`: from the scanned counts (entry key + 1 the
/// first slot of key), each particle's slot, in index order within a key (what `cell_order`
/// makes of the scatter's slots); returns the order and the cell table (entry e the first slot
/// of e, the last the particle count).
pub fn cell_scatter(keys: &[u32], mut cell_start: Vec<u32>) -> (Vec<u32>, Vec<u32>) {
    let mut order = vec![0u32; keys.len()];
    for (i, &k) in keys.iter().enumerate() {
        let slot = &mut cell_start[k as usize + 1];
        order[*slot as usize] = i as u32;
        *slot += 1;
    }
    (order, cell_start)
}

/// The whole grid build: returns `(order, cell_start)`, `order[k]` the original index of the
/// k-th particle in (cell, slice) order (stable: equal keys keep their original order), and the
/// particles of slice e are `order[cell_start[e]..cell_start[e + 1]]` (cell c is slices
/// `c * x_slices .. (c + 1) * x_slices`).
pub fn build_cell_table(grid: &GridParams, pos: &[[f64; 3]]) -> (Vec<u32>, Vec<u32>) {
    let (keys, counts) = cell_keys(grid, pos);
    // the counts' exclusive prefix sum (what the GPU's block scan computes, in integers)
    let scanned: Vec<u32> = counts
        .iter()
        .scan(0u32, |sum, &c| {
            let first = *sum;
            *sum += c;
            Some(first)
        })
        .collect();
    cell_scatter(&keys, scanned)
}

/// The grid build of the wall particles: `(order, wall_start)` as `build_cell_table`, but the
/// table holds only the wall rows (`GridParams::wall_rows`), where every wall particle lies.
pub fn build_wall_table(grid: &GridParams, pos: &[[f64; 3]]) -> (Vec<u32>, Vec<u32>) {
    let (order, full) = build_cell_table(grid, pos);
    let [dx, dy, dz] = grid.dims;
    let row = (dx * grid.x_slices) as usize;
    let mut table = Vec::with_capacity(grid.wall_table_len());
    for z in 0..dz {
        for y in [0, dy - 1].into_iter().take(grid.wall_rows() as usize) {
            let base = (z * dy + y) as usize * row;
            table.extend_from_slice(&full[base..base + row]);
        }
    }
    table.push(pos.len() as u32);
    // every particle in a wall row (the walls lie outside [0, size y]): the rows between are
    // empty in the full table, or the walls would be lost
    assert!((0..dz).all(|z| (1..dy.saturating_sub(1)).all(|y| {
        let base = (z * dy + y) as usize * row;
        full[base] == full[base + row]
    })));
    (order, table)
}

/// Calls `f(k, x_ik)` for every wall particle k within the 27 neighbouring cells of `p` (a wall
/// table, `build_wall_table`), with the minimum-image displacement `x_ik = p - x_k`.
pub fn for_each_wall_neighbor(
    grid: &GridParams,
    wall_start: &[u32],
    sorted_pos: &[[f64; 3]],
    p: impl Into<DVec3>,
    mut f: impl FnMut(usize, DVec3),
) {
    let p = p.into();
    let size = domain_size(grid);
    let periodic = [grid.periodic_x(), grid.periodic_z()];
    let slots = |n| grid.wall_cell_slots(wall_start, n);
    for_each_slot_of(grid, slots, grid.cell_coord(p), |k| {
        f(k, min_image(p - DVec3::from(sorted_pos[k]), size, periodic));
        true
    });
}

/// Calls `f(k)` for every slot of the 27 cells around cell `c`, in the shaders' order, until
/// `f` returns false.
pub fn for_each_slot(
    g: &GridParams,
    cell_start: &[u32],
    c: [i32; 3],
    f: impl FnMut(usize) -> bool,
) {
    for_each_slot_of(g, |n| g.cell_slots(cell_start, n), c, f)
}

/// `for_each_slot` over any table: `slots(n)` the slots of cell n.
fn for_each_slot_of(
    g: &GridParams,
    slots: impl Fn(u32) -> std::ops::Range<u32>,
    c: [i32; 3],
    mut f: impl FnMut(usize) -> bool,
) {
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let Some(n) = g.neighbor_cell(c, [dx, dy, dz]) else {
                    continue;
                };
                for k in slots(n) {
                    if !f(k as usize) {
                        return;
                    }
                }
            }
        }
    }
}

/// Calls `f(j, x_ij)` for every particle j (index into the cell-ordered arrays) within the 27
/// neighbouring cells of `p`, with the minimum-image displacement `x_ij = p - x_j`.
pub fn for_each_neighbor(
    grid: &GridParams,
    cell_start: &[u32],
    sorted_pos: &[[f64; 3]],
    p: impl Into<DVec3>,
    mut f: impl FnMut(usize, DVec3),
) {
    let p = p.into();
    let size = domain_size(grid);
    let periodic = [grid.periodic_x(), grid.periodic_z()];
    for_each_slot(grid, cell_start, grid.cell_coord(p), |j| {
        f(j, min_image(p - DVec3::from(sorted_pos[j]), size, periodic));
        true
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The wall table holds the first and last rows' entries of the full table: every cell's
    /// slots are the same, it is a fraction of the size, and the neighbour walk finds the same
    /// wall particles.
    #[test]
    fn the_wall_table_keeps_the_wall_rows_slots() {
        for (size, periodic) in [
            ([1.0, 0.8, 0.7], true),
            ([0.9, 0.3, 0.5], false),
            ([0.6, 0.1, 0.6], true),
        ] {
            let grid = GridParams::new(size, 0.1, periodic, periodic);
            let mut walls = Vec::new();
            for i in 0..30 {
                for k in 0..20 {
                    let (x, z) = (
                        size[0] * (i as f64 + 0.5) / 30.0,
                        size[2] * (k as f64 + 0.5) / 20.0,
                    );
                    walls.push([x, -0.025, z]);
                    walls.push([x, size[1] + 0.075, z]);
                }
            }
            let (order, full) = build_cell_table(&grid, &walls);
            let (worder, wall) = build_wall_table(&grid, &walls);
            assert_eq!(order, worder);
            assert_eq!(wall.len(), grid.wall_table_len());
            assert!(
                grid.dims[1] <= 2 || wall.len() < full.len() / 2,
                "{} of {}",
                wall.len(),
                full.len()
            );
            for cell in 0..grid.num_cells {
                let (w, f) = (
                    grid.wall_cell_slots(&wall, cell),
                    grid.cell_slots(&full, cell),
                );
                assert_eq!(w.collect::<Vec<_>>(), f.collect::<Vec<_>>(), "cell {cell}");
            }
            let sorted: Vec<[f64; 3]> = order.iter().map(|&o| walls[o as usize]).collect();
            for p in [
                [0.05, 0.02, 0.05],
                [size[0] - 0.01, size[1] - 0.03, 0.3],
                [0.3, size[1] / 2.0, 0.2],
            ] {
                let (mut a, mut b) = (Vec::new(), Vec::new());
                for_each_neighbor(&grid, &full, &sorted, p, |k, d| a.push((k, d)));
                for_each_wall_neighbor(&grid, &wall, &sorted, p, |k, d| b.push((k, d)));
                assert_eq!(a, b);
            }
        }
    }

    /// Counting, scanning and scattering unsorted keys gives the stable sort's order and a table
    /// whose entry e holds the number of keys below e.
    #[test]
    fn cell_scatter_gives_the_stable_order_and_the_table() {
        let grid = GridParams::new([1.0, 0.5, 0.7], 0.1, true, false);
        let entries = grid.table_len() as u32;
        let keys: Vec<u32> = (0..3000u32)
            .map(|i| (i.wrapping_mul(2654435761) >> 9) % (entries - 1))
            .collect();
        let mut counts = vec![0u32; grid.table_len()];
        for &k in &keys {
            counts[k as usize + 1] += 1;
        }
        let scanned = crate::sim::reference::scan::exclusive_scan(&counts, counts.len(), 0);
        let (order, table) = cell_scatter(&keys, scanned);
        let mut stable: Vec<u32> = (0..keys.len() as u32).collect();
        stable.sort_by_key(|&i| keys[i as usize]);
        assert_eq!(order, stable);
        for (e, &start) in table.iter().enumerate() {
            let below = keys.iter().filter(|&&k| k < e as u32).count() as u32;
            assert_eq!(start, below, "entry {e}");
        }
        assert_eq!(*table.last().unwrap(), keys.len() as u32);
    }
}
