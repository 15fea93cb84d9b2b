//! f64 mirror of shaders/forcing.wgsl (`apply_forcing`): one frame's large-scale forcing per
//! particle, from the same uniform.
use crate::sim::forces::forcing::ForcingParams;

/// The table's (dT/dt, dq/dt) at height y: linear between layer centres, clamped at the outer
/// ones (forcing.wgsl `table_at`).
pub fn table_at(p: &ForcingParams, y: f64) -> [f64; 2] {
    let n = p.n_layers as usize;
    let t = (y / p.layer_height as f64 - 0.5).clamp(0.0, (n - 1) as f64);
    let k0 = t.floor() as usize;
    let k1 = (k0 + 1).min(n - 1);
    let f = t - k0 as f64;
    let (a, b) = (p.layers[k0], p.layers[k1]);
    [0, 1].map(|c| a[c] as f64 + f * (b[c] as f64 - a[c] as f64))
}

/// `apply_forcing` over every particle: T and v of `thermo` (x, y), at the heights of `pos`.
pub fn apply_forcing(p: &ForcingParams, pos: &[[f64; 3]], thermo: &mut [[f64; 4]]) {
    let dt = p.dt as f64;
    for (x, th) in pos.iter().zip(thermo.iter_mut()) {
        let mut rate = table_at(p, x[1]);
        if x[1] < p.surface_layer as f64 {
            rate[0] += p.surface_heat as f64;
            rate[1] += p.surface_moisture as f64;
        }
        th[0] += dt * rate[0];
        th[1] = (th[1] + dt * rate[1]).max(0.0);
    }
}
