//! f64 mirror of shaders/entrainment.wgsl (`apply_entrainment`): one frame's entrainment per
//! particle, from the same uniform.
use crate::sim::forces::entrainment::EntrainmentParams;

/// `apply_entrainment` over every particle: T, v and w of `thermo` (x, y, z), at the heights of
/// `pos` with the vertical speeds of `vel`.
pub fn apply_entrainment(
    p: &EntrainmentParams,
    pos: &[[f64; 3]],
    vel: &[[f64; 3]],
    thermo: &mut [[f64; 4]],
) {
    let n = p.n_layers as usize;
    let column = |rows: &[[f32; 4]; crate::sim::forces::forcing::MAX_FORCING_LAYERS], k: usize| {
        rows[k].map(|x| x as f64)
    };
    for ((x, u), th) in pos.iter().zip(vel).zip(thermo.iter_mut()) {
        let y = x[1];
        let t = (y / p.layer_height as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let k0 = t.floor() as usize;
        let k1 = (k0 + 1).min(n - 1);
        let f = t - k0 as f64;
        if th[2] > 0.0 {
            let (e0, e1) = (column(&p.env, k0), column(&p.env, k1));
            let (a, b) = ((1.0 - f) * e0[2], f * e1[2]);
            if a + b <= 0.0 {
                continue;
            }
            let env = [0, 1].map(|c| (a * e0[c] + b * e1[c]) / (a + b));
            let r = -(-(p.rate as f64) * u[1].abs() * p.dt as f64).exp_m1();
            let t_env = env[0] - p.lapse as f64 * y;
            th[0] -= r * (th[0] - t_env);
            th[1] -= r * (th[1] - env[1]);
            th[2] -= r * th[2];
        } else {
            let (g0, g1) = (column(&p.gain, k0), column(&p.gain, k1));
            th[0] += g0[0] + f * (g1[0] - g0[0]);
            th[1] = (th[1] + g0[1] + f * (g1[1] - g0[1])).max(0.0);
        }
    }
}
