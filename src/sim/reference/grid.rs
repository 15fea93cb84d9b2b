//! CPU mirror of the neighbour-grid build: a stable sort of particles by (cell, x slice), and
//! the cell table with one entry per slice.
use crate::sim::grid_params::GridParams;

/// Returns `(order, cell_start)`: `order[k]` is the original index of the k-th particle in
/// (cell, slice) order (stable: equal keys keep their original order), and the particles of
/// slice e are `order[cell_start[e]..cell_start[e + 1]]` (`GridParams::table_len` entries; cell
/// c is slices `c * x_slices .. (c + 1) * x_slices`).
pub fn build_cell_table(grid: &GridParams, pos: &[[f64; 3]]) -> (Vec<u32>, Vec<u32>) {
    let keys: Vec<u32> = pos.iter().map(|p| grid.slice_key(*p)).collect();
    let mut order: Vec<u32> = (0..pos.len() as u32).collect();
    order.sort_by_key(|&i| keys[i as usize]);
    let mut cell_start = vec![0u32; grid.table_len()];
    for &k in &keys {
        cell_start[k as usize + 1] += 1;
    }
    for e in 0..grid.table_len() - 1 {
        cell_start[e + 1] += cell_start[e];
    }
    (order, cell_start)
}

/// Calls `f(j, x_ij)` for every particle j (index into the cell-ordered arrays) within the 27
/// neighbouring cells of `p`, with the minimum-image displacement `x_ij = p - x_j`.
pub fn for_each_neighbor(
    grid: &GridParams,
    cell_start: &[u32],
    sorted_pos: &[[f64; 3]],
    p: [f64; 3],
    mut f: impl FnMut(usize, [f64; 3]),
) {
    let size = grid.domain_size.map(|v| v as f64);
    let periodic = [grid.periodic_x(), grid.periodic_z()];
    let c = grid.cell_coord(p);
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let Some(n) = grid.neighbor_cell(c, [dx, dy, dz]) else {
                    continue;
                };
                for j in grid.cell_slots(cell_start, n) {
                    let q = sorted_pos[j as usize];
                    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                    f(j as usize, super::kernels::min_image(d, size, periodic));
                }
            }
        }
    }
}

/// Mirror of `cell_keys` (grid.wgsl): the (cell, x slice) key of each position.
pub fn cell_keys(grid: &GridParams, pos: &[[f64; 3]]) -> Vec<u32> {
    pos.iter().map(|p| grid.slice_key(*p)).collect()
}

/// Mirror of `permute4`/`permute2`: `dst[i] = src[order[i]]`.
pub fn permute<T: Copy>(order: &[u32], src: &[T]) -> Vec<T> {
    order.iter().map(|&o| src[o as usize]).collect()
}
