//! The adaptive particle levels, defined here alone. `MAX_LEVEL` is the finest level: the
//! config's range of `adaptive.max_level`, the rows of the PBF and smoothing programs' level
//! tables, the level clamps host and GPU apply, and the room of the adaptive counters; the
//! shaders get it from the prelude (`gpu::shaders::Prelude`), so no WGSL file repeats it. A
//! level-l particle has the kernel radius h0 2^(-l/3) and the mass m0 2^(-l): a split halves
//! the mass and keeps the particles per kernel.

/// The finest adaptive level. The WGSL level tables are read by select chains unrolled for 8
/// rows (pbf.wgsl `lv_of`, smoothing.wgsl `level_row`) and pbf.wgsl packs a level into lambda's
/// 3 low bits; a test and the shaders' `const_assert`s hold them to it.
pub const MAX_LEVEL: u32 = 7;

/// Kernel radius of a level-`level` particle, h0 2^(-level/3).
pub fn radius(h0: f64, level: u32) -> f64 {
    h0 * (-(level as f64) / 3.0).exp2()
}

/// Mass of a level-`level` particle, m0 2^(-level).
pub fn mass(m0: f64, level: u32) -> f64 {
    m0 * (-(level as f64)).exp2()
}

/// The poly6 kernel (Mueller et al. 2003) of radius `h` at squared distance `r2`, in f64: the
/// host's one definition (the level-0 mass, the walls' density, the diagnostics, the mirrors).
pub fn poly6(r2: f64, h: f64) -> f64 {
    let h2 = h * h;
    if r2 >= h2 {
        return 0.0;
    }
    let d = h2 - r2;
    315.0 / (64.0 * std::f64::consts::PI * h.powi(9)) * d * d * d
}
