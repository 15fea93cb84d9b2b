//! `export.detail`: procedural cloud detail finer than the particles, evaluated where each voxel's
//! air was at the last rest reset (`sim::rest`), so the noise moves with the flow instead of the
//! cloud moving through a fixed noise.
//!
//! Per voxel of the splat:
//! - rest coordinate of field f: r_f = x - D_f, where D_f = sum_j V_j W (D~_j,f) / sum_j V_j W
//!   is the Shepard interpolation, with the density kernel W, of the particles' displacements
//!   since the reset D~_j,f, themselves first smoothed over the particles within
//!   `rest_smoothing` x h (1.5 by default; `rest_smooth`), so that the particles' shuffle at
//!   the particle scale averages out of the rest coordinate (minimum image on periodic axes, so
//!   r_f is continuous across the periodic faces);
//! - noise n = sin(t) N(r_A) + cos(t) N(r_B), t = (pi / 2) w_A, with the rest clock's triangle
//!   weights (w_A + w_B = 1, linear in time): an equal-power cross-fade (the contrast stays the
//!   same) that turns by the same angle every frame, pi / P, so two consecutive frames share
//!   cos(pi / P) of their noise (0.92 at P = 8) where the linear weights' worst step shared
//!   0.89;
//! - N is fractal value noise (`ground::noise::value_noise3`, tiled over the periodic extents):
//!   octave o has wavelength scale / 2^o and weight 2^-o; an octave under two voxels is left out
//!   (it would alias). Per octave, with g in [-1, 1): billowy = 2|g| - 1 (round puffs, sharp
//!   creases), wispy = 2 (1 - |g|)^2 - 1 (thin ridges); N is their weighted mean, in [-1, 1];
//! - detailed density = density x max(0, 1 + amplitude n), before the threshold; then every
//!   detailed value is scaled by one factor per frame, sum(undetailed active) / sum(detailed), so
//!   the grid's total mass is the undetailed one (up to what the threshold cuts).
use crate::config::{DetailCharacter, ShotConfig};
use crate::ground::noise::{fold_seed, lattice_for_extent, pcg_hash, value_noise3};
use crate::ground::rest::{RestCodec, RestFrame};

/// Where the noise is evaluated: the rest frame (the product) or world space (only for the
/// measurement in `bench::detail`, the comparison of docs/RENDERING.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoiseSpace {
    Rest,
    World,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DetailParams {
    pub scale: f64,
    pub amplitude: f64,
    pub octaves: u32,
    pub character: DetailCharacter,
    pub seed: u32,
    pub space: NoiseSpace,
}

impl DetailParams {
    /// `None` when `export.detail.enabled` is off.
    pub fn from_config(cfg: &ShotConfig) -> Option<Self> {
        let d = &cfg.export.detail;
        d.enabled.then(|| Self {
            scale: d.scale,
            amplitude: d.amplitude,
            octaves: d.octaves,
            character: d.character,
            seed: fold_seed(cfg.seed),
            space: NoiseSpace::Rest,
        })
    }
}

/// The rest positions of a frame as the splat reads them.
#[derive(Debug, Clone, Copy)]
pub struct RestInput<'a> {
    /// One entry per particle of the splatted state, same order.
    pub rest: &'a RestFrame,
    pub codec: RestCodec,
    /// Blend weights of field A and B (`ground::rest::RestClock::weights`).
    pub weights: [f64; 2],
    /// Field B is in use (`RestClock::dual`): its grid is written.
    pub dual: bool,
}

/// One octave's lattice: (cell, period) along x and z, cell along y, seed.
#[derive(Debug, Clone, Copy)]
struct Octave {
    cx: f64,
    px: u32,
    cy: f64,
    cz: f64,
    pz: u32,
    seed: u32,
    weight: f64,
}

/// The noise of one frame: octaves laid out on the domain.
#[derive(Debug, Clone)]
pub struct DetailNoise {
    octaves: Vec<Octave>,
    character: DetailCharacter,
    pub amplitude: f64,
    pub space: NoiseSpace,
    pub weights: [f64; 2],
}

impl DetailNoise {
    pub fn new(p: &DetailParams, domain: [f64; 3], voxel: f64, weights: [f64; 2]) -> Self {
        let mut octaves = Vec::new();
        let mut total = 0.0;
        for o in 0..p.octaves {
            let lambda = p.scale / f64::from(1u32 << o);
            if lambda < 2.0 * voxel {
                break;
            }
            let (cx, px) = lattice_for_extent(domain[0], lambda);
            let (cz, pz) = lattice_for_extent(domain[2], lambda);
            let w = 0.5f64.powi(o as i32);
            total += w;
            octaves.push(Octave {
                cx,
                px,
                cy: lambda,
                cz,
                pz,
                seed: pcg_hash(p.seed ^ 0x00de_7a11 ^ o),
                weight: w,
            });
        }
        for o in &mut octaves {
            o.weight /= total;
        }
        Self {
            octaves,
            character: p.character,
            amplitude: p.amplitude,
            space: p.space,
            weights,
        }
    }

    /// Octaves in use (0: the voxels are too coarse for any; the detail is then a no-op).
    pub fn octave_count(&self) -> usize {
        self.octaves.len()
    }

    /// Fractal noise in [-1, 1] at a point (m).
    pub fn noise(&self, p: [f64; 3]) -> f64 {
        let mut n = 0.0;
        for o in &self.octaves {
            let v = value_noise3(p[0], p[2], p[1] / o.cy, o.cx, o.cz, o.px, o.pz, o.seed);
            let g = (2.0 * v - 1.0).abs();
            let s = match self.character {
                DetailCharacter::Billowy => 2.0 * g - 1.0,
                DetailCharacter::Wispy => 2.0 * (1.0 - g) * (1.0 - g) - 1.0,
            };
            n += o.weight * s;
        }
        n
    }

    /// The blended noise of a voxel at world position `x` with rest coordinates `rest`.
    pub fn blended(&self, x: [f64; 3], rest: [[f64; 3]; 2]) -> f64 {
        if self.octaves.is_empty() {
            return 0.0;
        }
        let [wa, wb] = self.weights;
        let (ra, rb) = match self.space {
            NoiseSpace::Rest => (rest[0], rest[1]),
            NoiseSpace::World => (x, x),
        };
        let a = if wa > 0.0 { self.noise(ra) } else { 0.0 };
        let b = if wb > 0.0 { self.noise(rb) } else { 0.0 };
        // equal-power cross-fade at a constant angular rate: the blend turns from one field to
        // the other by the same angle every frame (the clock's weight is linear in time)
        let th = std::f64::consts::FRAC_PI_2 * wa / (wa + wb);
        th.sin() * a + th.cos() * b
    }

    /// Density factor of a voxel before the frame's normalisation.
    pub fn factor(&self, x: [f64; 3], rest: [[f64; 3]; 2]) -> f64 {
        (1.0 + self.amplitude * self.blended(x, rest)).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(character: DetailCharacter) -> DetailParams {
        DetailParams {
            scale: 40.0,
            amplitude: 0.6,
            octaves: 3,
            character,
            seed: 7,
            space: NoiseSpace::Rest,
        }
    }

    #[test]
    fn noise_is_bounded_tiles_and_skips_aliasing_octaves() {
        let dom = [800.0, 400.0, 800.0];
        for ch in [DetailCharacter::Billowy, DetailCharacter::Wispy] {
            let d = DetailNoise::new(&params(ch), dom, 5.0, [1.0, 0.0]);
            assert_eq!(d.octave_count(), 3);
            let (mut lo, mut hi) = (1.0f64, -1.0f64);
            for k in 0..3000 {
                let p = [
                    k as f64 * 7.31 % 800.0,
                    k as f64 * 3.7 % 400.0,
                    k as f64 * 11.9 % 800.0,
                ];
                let n = d.noise(p);
                assert!((-1.0..=1.0).contains(&n));
                let m = d.noise([p[0] + 800.0, p[1], p[2] - 800.0]);
                assert!((n - m).abs() < 1e-9);
                lo = lo.min(n);
                hi = hi.max(n);
            }
            assert!(hi - lo > 0.8, "{ch:?}: {lo}..{hi}");
        }
        // 40, 20, 10 m octaves at 8 m voxels: only 40 and 20 stay; at 25 m none
        let d = DetailNoise::new(&params(DetailCharacter::Billowy), dom, 8.0, [1.0, 0.0]);
        assert_eq!(d.octave_count(), 2);
        let d = DetailNoise::new(&params(DetailCharacter::Billowy), dom, 25.0, [1.0, 0.0]);
        assert_eq!(d.octave_count(), 0);
        assert_eq!(d.factor([1.0; 3], [[1.0; 3]; 2]), 1.0);
    }

    #[test]
    fn world_space_ignores_the_rest_coordinate() {
        let mut p = params(DetailCharacter::Wispy);
        let dom = [800.0, 400.0, 800.0];
        let rest = DetailNoise::new(&p, dom, 5.0, [0.3, 0.7]);
        p.space = NoiseSpace::World;
        let world = DetailNoise::new(&p, dom, 5.0, [0.3, 0.7]);
        let x = [100.0, 50.0, 30.0];
        let r = [[140.0, 70.0, 10.0], [120.0, 60.0, 35.0]];
        assert_eq!(world.blended(x, r), world.blended(x, [x, x]));
        assert_eq!(rest.blended(x, [x, x]), world.blended(x, r));
        assert_ne!(rest.blended(x, r), world.blended(x, r));
    }
}
