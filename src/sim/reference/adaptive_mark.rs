//! f64 mirror of shaders/adaptive_mark.wgsl (`adaptive_mark`): shape energy and the split and
//! merge marks.
use super::adaptive::RefParticles;
use super::common::{children, grid_min_image, inside_walls, level_radius};
use super::grid::for_each_slot;
use crate::sim::adaptive::{AdaptiveParams, FLAG_MERGE, FLAG_SPLIT};
use crate::sim::grid_params::GridParams;

fn split_fits(
    g: &GridParams,
    prm: &AdaptiveParams,
    cell_start: &[u32],
    p: &RefParticles,
    i: usize,
) -> bool {
    let x = p.xyz(i);
    let [id, level] = p.info[i];
    let [a, b] = children(g, prm.h0 as f64, prm.split_offset as f64, x, id, level);
    if !inside_walls(a, g) || !inside_walls(b, g) {
        return false;
    }
    let r = prm.min_distance as f64 * level_radius(prm.h0 as f64, level + 1);
    let mut ok = true;
    for_each_slot(g, cell_start, g.cell_coord(x), |k| {
        if k != i {
            let q = p.xyz(k);
            let (da, db) = (grid_min_image(a - q, g), grid_min_image(b - q, g));
            if da.dot(da) < r * r || db.dot(db) < r * r {
                ok = false;
            }
        }
        ok
    });
    ok
}

/// Shape energy into `thermo.w` and the marks of the first `prm.count` particles.
#[allow(clippy::needless_range_loop)] // indexed like the shader: split_fits reads all of `p`
pub fn adaptive_mark(
    g: &GridParams,
    prm: &AdaptiveParams,
    cell_start: &[u32],
    p: &mut RefParticles,
    flags: &mut [u32],
) {
    for i in 0..prm.count as usize {
        let e = prm.kp as f64 * (1.0 - (-(prm.kc as f64) * p.thermo[i][2]).exp());
        p.thermo[i][3] = e;
        let level = p.info[i][1];
        flags[i] = if e < prm.merge_threshold as f64 && level > 0 {
            FLAG_MERGE
        } else if e > prm.split_threshold as f64
            && level < prm.max_level
            && split_fits(g, prm, cell_start, p, i)
        {
            FLAG_SPLIT
        } else {
            0
        };
    }
}
