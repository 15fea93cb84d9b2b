//! The f64 helpers every mirror shares: shaders/shared/common.wgsl (kernels, minimum image; its
//! cell helpers `cell_coord`, `neighbor_cell`, `slice_key` are methods of
//! [`GridParams`]) and shaders/shared/adaptive.wgsl (level radius, split direction, wrapping,
//! walls), same names.
use crate::sim::grid_params::GridParams;
use glam::DVec3;
use std::f64::consts::PI;

/// The shaders' `pcg_hash` (shared/common.wgsl); one mirror for noise and split directions.
pub use crate::ground::noise::pcg_hash;
/// The host's kernel and minimum image, which the mirrors share with the diagnostics.
pub use crate::sim::kernels::{domain_size, min_image, poly6};

pub fn spiky_grad(xij: DVec3, r: f64, h: f64) -> DVec3 {
    if r >= h || r <= 1e-9 * h {
        return DVec3::ZERO;
    }
    let d = h - r;
    (-45.0 / (PI * h.powi(6)) * d * d / r) * xij
}

pub fn poly6_sym(r2: f64, hi: f64, hj: f64) -> f64 {
    0.5 * (poly6(r2, hi) + poly6(r2, hj))
}

pub fn spiky_grad_sym(xij: DVec3, r: f64, hi: f64, hj: f64) -> DVec3 {
    0.5 * (spiky_grad(xij, r, hi) + spiky_grad(xij, r, hj))
}

/// [`min_image`] across the grid's periodic faces (the shaders' `min_image(d, grid)`).
pub fn grid_min_image(d: DVec3, g: &GridParams) -> DVec3 {
    min_image(d, domain_size(g), [g.periodic_x(), g.periodic_z()])
}

pub fn level_radius(h0: f64, level: u32) -> f64 {
    h0 * (-(level as f64) / 3.0).exp2()
}

/// Unit direction of a split from the particle id (uniform on the sphere).
pub fn split_dir(id: u32) -> DVec3 {
    let a = pcg_hash(id);
    let b = pcg_hash(a);
    let u = (a >> 8) as f64 / 16777216.0;
    let v = (b >> 8) as f64 / 16777216.0;
    let z = 1.0 - 2.0 * u;
    let s = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f64::consts::TAU * v;
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}

pub fn wrap_pos(p: DVec3, g: &GridParams) -> DVec3 {
    let mut r = p;
    let (lo, sz) = (DVec3::from(g.domain_min.map(f64::from)), domain_size(g));
    if g.periodic_x() {
        r.x -= sz.x * ((r.x - lo.x) / sz.x).floor();
    }
    if g.periodic_z() {
        r.z -= sz.z * ((r.z - lo.z) / sz.z).floor();
    }
    r
}

pub fn inside_walls(p: DVec3, g: &GridParams) -> bool {
    let lo = DVec3::from(g.domain_min.map(f64::from));
    let hi = lo + domain_size(g);
    let within = |a: usize| p[a] >= lo[a] && p[a] <= hi[a];
    within(1) && (g.periodic_x() || within(0)) && (g.periodic_z() || within(2))
}

/// The two children of a split of a level-`level` particle at `x` (the `off` of
/// adaptive_mark.wgsl's `split_fits` and adaptive_split.wgsl), wrapped.
pub fn children(
    g: &GridParams,
    h0: f64,
    split_offset: f64,
    x: DVec3,
    id: u32,
    level: u32,
) -> [DVec3; 2] {
    let hc = level_radius(h0, level + 1);
    let off = (split_offset * hc) * split_dir(id);
    [wrap_pos(x + off, g), wrap_pos(x - off, g)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Poly6 integrates to 1 over its support (normalisation), checked by a midpoint sum.
    #[test]
    fn poly6_is_normalised() {
        let h = 1.3;
        let n = 60;
        let dx = 2.0 * h / n as f64;
        let mut s = 0.0;
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let p = [i, j, k].map(|v| -h + (v as f64 + 0.5) * dx);
                    s += poly6(p[0] * p[0] + p[1] * p[1] + p[2] * p[2], h) * dx * dx * dx;
                }
            }
        }
        assert!((s - 1.0).abs() < 2e-3, "integral {s}");
    }

    #[test]
    fn split_dir_is_unit_and_spread() {
        let mut mean = DVec3::ZERO;
        for id in 0..4000 {
            let d = split_dir(id);
            assert!((d.dot(d) - 1.0).abs() < 1e-12);
            mean += d / 4000.0;
        }
        assert!(mean.length() < 0.05, "biased directions {mean:?}");
    }
}
