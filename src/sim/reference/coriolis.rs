//! f64 mirror of shaders/coriolis.wgsl (`apply_coriolis`): a substep's Coriolis turn about the
//! geostrophic wind and the surface stress, per particle, from the same uniform.
use crate::sim::forces::coriolis::CoriolisParams;
use crate::sim::reference::thermo::profile_wind;

/// `apply_coriolis` over every particle: the horizontal velocity (x, z) of `vel`, at the heights
/// of `pos`.
pub fn apply_coriolis(p: &CoriolisParams, pos: &[[f64; 3]], vel: &mut [[f64; 4]]) {
    let (c, s) = (p.turn_cos as f64, p.turn_sin as f64);
    let ground = p.ground.map(|g| g as f64);
    for (x, v) in pos.iter().zip(vel.iter_mut()) {
        let mut u = [v[0], v[2]];
        if p.n_levels > 0 {
            let g = profile_wind(&p.levels[..p.n_levels as usize], x[1]);
            let a = [u[0] - g[0], u[1] - g[1]];
            u = [g[0] + c * a[0] - s * a[1], g[1] + s * a[0] + c * a[1]];
        }
        if x[1] < p.surface_layer as f64 && p.drag > 0.0 {
            let over = [u[0] - ground[0], u[1] - ground[1]];
            let speed = over[0].hypot(over[1]);
            if speed > 0.0 {
                let k = (p.drag as f64 / speed).min(1.0);
                u = [u[0] - k * over[0], u[1] - k * over[1]];
            }
        }
        v[0] = u[0];
        v[2] = u[1];
    }
}
