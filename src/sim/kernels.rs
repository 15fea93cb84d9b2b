//! The SPH kernel and the minimum image in f64, as the host evaluates them (the boundary
//! particles' density, the diagnostics); the mirrors share them (`reference::common`), the
//! shaders have their f32 twins in shaders/shared/common.wgsl.
use crate::sim::grid_params::GridParams;
use glam::DVec3;

pub use crate::ground::levels::poly6;

/// Minimum-image displacement; `periodic` = [x, z].
pub fn min_image(d: impl Into<DVec3>, size: impl Into<DVec3>, periodic: [bool; 2]) -> DVec3 {
    let (mut r, size) = (d.into(), size.into());
    if periodic[0] {
        r.x -= size.x * (r.x / size.x).round();
    }
    if periodic[1] {
        r.z -= size.z * (r.z / size.z).round();
    }
    r
}

/// The grid's domain size, widened.
pub fn domain_size(g: &GridParams) -> DVec3 {
    DVec3::from(g.domain_size.map(f64::from))
}
