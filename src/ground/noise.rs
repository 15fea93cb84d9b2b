//! Hash-based value noise for the ground heating pattern (eq. 5), f64 mirror of the WGSL
//! functions of the same names in shaders/thermo.wgsl.
//!
//! Definition (identical on both sides):
//! - `pcg_hash(u32) -> u32`: the PCG-RXS-M-XS permutation of Jarzynski & Olano, "Hash
//!   Functions for GPU Rendering" (JCGT 2020), wrapping u32 arithmetic;
//! - `lattice_value(ix, iz, it, seed)`: `pcg(ix ^ pcg(iz ^ pcg(it ^ pcg(seed))))` (indices as
//!   two's-complement u32), top 24 bits scaled into [0, 1) — exactly representable in f32, so
//!   the GPU and the mirror agree bit for bit on the lattice values;
//! - `value_noise3(x, z, t, ...)`: the lattice values at the 8 corners of the unit cell of
//!   `(x / cell_x, z / cell_z, t)` interpolated with the quintic fade 6u^5 - 15u^4 + 10u^3
//!   (C2-continuous); lattice indices along x and z wrap with periods `period_x`, `period_z` so
//!   the pattern tiles a periodic domain without a seam. The result lies in [0, 1).
//!
//! The only GPU/mirror difference is f32 rounding of the fractional coordinates and the
//! interpolation (about 1e-6); the noise is continuous, so a lattice index that rounds
//! differently near a cell face still gives nearly the same value.

/// PCG-RXS-M-XS 32-bit hash.
pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747796405).wrapping_add(2891336453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277803737);
    (word >> 22) ^ word
}

/// Value in [0, 1) attached to an integer lattice point.
pub fn lattice_value(ix: i32, iz: i32, it: i32, seed: u32) -> f64 {
    let h = pcg_hash(ix as u32 ^ pcg_hash(iz as u32 ^ pcg_hash(it as u32 ^ pcg_hash(seed))));
    (h >> 8) as f64 * (1.0 / 16_777_216.0)
}

/// Quintic fade 6u^5 - 15u^4 + 10u^3.
pub fn fade(u: f64) -> f64 {
    u * u * u * (u * (u * 6.0 - 15.0) + 10.0)
}

fn wrap(i: i32, period: i32) -> i32 {
    i.rem_euclid(period.max(1))
}

/// Value noise over the ground plane and time, in [0, 1). `x`, `z` in metres, `cell_x`,
/// `cell_z` the lattice spacing in metres, `t` in lattice units (time * speed).
#[allow(clippy::too_many_arguments)]
pub fn value_noise3(
    x: f64,
    z: f64,
    t: f64,
    cell_x: f64,
    cell_z: f64,
    period_x: u32,
    period_z: u32,
    seed: u32,
) -> f64 {
    let p = [x / cell_x, z / cell_z, t];
    let f = p.map(f64::floor);
    let u = [0, 1, 2].map(|a| fade(p[a] - f[a]));
    let i = f.map(|v| v as i32);
    let (px, pz) = (period_x as i32, period_z as i32);
    let corner = |dx: i32, dz: i32, dt: i32| {
        lattice_value(wrap(i[0] + dx, px), wrap(i[1] + dz, pz), i[2] + dt, seed)
    };
    // Same form as WGSL `mix`.
    let lerp = |a: f64, b: f64, s: f64| a * (1.0 - s) + b * s;
    let mut along_t = [0.0; 2];
    for (dt, out) in along_t.iter_mut().enumerate() {
        let dt = dt as i32;
        let a = lerp(corner(0, 0, dt), corner(1, 0, dt), u[0]);
        let b = lerp(corner(0, 1, dt), corner(1, 1, dt), u[0]);
        *out = lerp(a, b, u[1]);
    }
    lerp(along_t[0], along_t[1], u[2])
}

/// Lattice layout of the heating noise for a domain extent: the number of lattice cells along
/// an axis is `round(size / scale)` (at least 1) and the cell is `size / cells`, so the noise
/// tiles the periodic extent exactly. Returns `(cell, period)`.
pub fn lattice_for_extent(size: f64, scale: f64) -> (f64, u32) {
    let cells = (size / scale.max(1e-9)).round().max(1.0);
    (size / cells, cells as u32)
}

/// Folds the 64-bit shot seed into the 32-bit noise seed.
pub fn fold_seed(seed: u64) -> u32 {
    (seed ^ (seed >> 32)) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_in_unit_range_deterministic_and_tiles() {
        let (cx, px) = lattice_for_extent(1000.0, 300.0);
        let (cz, pz) = lattice_for_extent(800.0, 300.0);
        assert_eq!((px, pz), (3, 3));
        let mut lo: f64 = 1.0;
        let mut hi: f64 = 0.0;
        for k in 0..2000 {
            let x = (k as f64 * 37.77) % 1000.0;
            let z = (k as f64 * 53.13) % 800.0;
            let t = k as f64 * 0.013;
            let n = value_noise3(x, z, t, cx, cz, px, pz, 7);
            assert!((0.0..1.0).contains(&n));
            assert_eq!(n, value_noise3(x, z, t, cx, cz, px, pz, 7));
            // Tiles across the periodic extent.
            let m = value_noise3(x + 1000.0, z - 800.0, t, cx, cz, px, pz, 7);
            assert!((n - m).abs() < 1e-9, "{n} vs {m}");
            lo = lo.min(n);
            hi = hi.max(n);
        }
        assert!(hi - lo > 0.5, "noise has too little contrast: {lo}..{hi}");
        // Another seed gives another pattern.
        let a = value_noise3(123.0, 456.0, 0.3, cx, cz, px, pz, 7);
        let b = value_noise3(123.0, 456.0, 0.3, cx, cz, px, pz, 8);
        assert_ne!(a, b);
    }

    #[test]
    fn noise_is_continuous_across_lattice_faces() {
        let (c, p) = (100.0, 10);
        for face in [100.0, 200.0, 700.0] {
            let a = value_noise3(face - 1e-6, 50.0, 0.5, c, c, p, p, 3);
            let b = value_noise3(face + 1e-6, 50.0, 0.5, c, c, p, p, 3);
            assert!((a - b).abs() < 1e-6);
        }
    }
}
