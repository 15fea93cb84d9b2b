//! `export.detail`: procedural cloud detail finer than the particles, where clouds have it: at
//! the surface. Noise displaces the cloud's boundary (billows that bulge out, creases that eat
//! in, several octaves for the cauliflower look), the boundary is made as sharp as the voxels
//! allow, and the core keeps its density. The noise is evaluated where each voxel's air was at
//! the last rest reset (`ground::rest`), so it moves with the flow instead of the cloud moving
//! through a fixed noise.
//!
//! Per voxel of the splat, from sums over the particles (the density kernel W, volumes V_j):
//! - cloud fraction c = sum_j V_j W s_j / sum_j V_j W, with s_j = min(1, q_j / q_edge) the
//!   particle's share of "cloud" (q_edge = `EDGE_WATER`: a particle with at least 0.05 g/kg of
//!   cloud water counts fully); c is 1 inside the cloud, 0 in clear air;
//! - distance to the boundary phi = h_c C^-1(c), positive inside: C is the cloud fraction at
//!   signed distance u h from a plane boundary (the poly6 kernel integrated over a half space,
//!   `plane_fraction`), h_c the mean kernel radius of the cloudy particles around. Exact for a
//!   plane boundary; phi = h_c wherever every particle in reach is cloud (c = 1);
//! - the surface's character omega in [0, 1] (0 billowy, 1 wispy): wispy where the outward
//!   normal (-grad c) points down (the cloud's base) and where the cloud is thin (q_in below a
//!   few q_edge), billowy elsewhere (`DetailCharacter` sets the rest);
//! - displacement D = amplitude sum_o lambda_o N_o(r), octaves of wavelength lambda_o = scale /
//!   2^o (an octave under two voxels is left out: it would alias); N_o the octave's billowy
//!   2|g| - 1 and wispy 2 (1 - |g|)^2 - 1 value noise mixed by omega; r the voxel's rest
//!   coordinate (field A and B cross-faded: D = sin(t) D(r_A) + cos(t) D(r_B), t = (pi / 2) w_A,
//!   an equal-power fade that turns by pi / P every frame);
//! - detailed density = q_in S(phi + D): q_in = d0 / c the density of the cloud at the edge
//!   without the kernel's fade (d0 itself where c = 1), S a smoothstep from 0 to 1 over
//!   [-w, w], w one voxel (sharp) to two (wispy);
//! - mass: one factor per frame on the edge, detailed (1 + k m), m = 1 - smoothstep(0, h_c,
//!   phi) (1 at the surface and outside, 0 in the core), k such that the total is the
//!   undetailed one: the core (c = 1, phi = h_c) keeps its density exactly.
use crate::config::{DetailCharacter, ShotConfig};
use crate::ground::noise::{fold_seed, lattice_for_extent, pcg_hash, value_noise3};
use crate::ground::rest::{RestCodec, RestFrame};

/// Cloud water (kg/kg) from which a particle counts fully as cloud in the cloud fraction; a
/// thinner one counts in proportion (so a particle condensing joins the cloud smoothly). 0.05
/// g/kg is about 0.05 g/m^3, an extinction of 0.008 /m: a visible haze over tens of metres.
pub const EDGE_WATER: f64 = 5.0e-5;

/// Shortest octave, in voxels: a displaced surface that is then made sharp shows an octave of
/// fewer voxels as speckle.
pub const MIN_WAVELENGTH_VOXELS: f64 = 4.0;
/// Half widths of the sharpened boundary in voxels: billowy and wispy (10%-90% over 1.2 times
/// the half width along the distance).
pub const SHARP_VOXELS: f64 = 1.25;
pub const SOFT_VOXELS: f64 = 2.5;

/// Where the noise is evaluated: the rest frame (the product) or world space (only for the
/// measurement in `bench::detail`, the comparison of docs/RENDERING.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoiseSpace {
    Rest,
    World,
}

#[derive(Debug, Clone, PartialEq)]
pub struct DetailParams {
    /// Wavelength of the first octave (m).
    pub scale: f64,
    /// Displacement of each octave as a fraction of its wavelength.
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
            scale: d.scale.unwrap_or(2.0 * cfg.domain.spacing),
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

/// A particle's share of "cloud" in the cloud fraction: s = min(1, q / q_edge), q and q_edge in
/// the density grid's units.
pub fn cloud_share(cloud: f64, edge_water: f64) -> f64 {
    if cloud > 0.0 {
        (cloud / edge_water).min(1.0)
    } else {
        0.0
    }
}

/// The kernel sums at a point that the detail reads; `add` is one particle's term.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EdgeSums {
    /// sum V W, sum V W q (the undetailed density), sum V W s, sum V W s h.
    pub cov: f64,
    pub dens: f64,
    pub cloud: f64,
    pub cloud_h: f64,
    /// Gradients of sum V W and of sum V W s (1/m).
    pub grad_cov: [f64; 3],
    pub grad_cloud: [f64; 3],
}

impl EdgeSums {
    /// One particle's term: kernel weight `w` = V c (h^2 - r^2)^3, `dw` = -6 V c (h^2 - r^2)^2
    /// (so grad W = dw (x - x_j)), offset `e` = x - x_j (m), its share `s` and radius `h`.
    #[inline]
    pub fn add(&mut self, w: f64, dw: f64, e: [f64; 3], q: f64, s: f64, h: f64) {
        self.cov += w;
        self.dens += w * q;
        self.cloud += w * s;
        self.cloud_h += w * s * h;
        for (a, &ea) in e.iter().enumerate() {
            let g = dw * ea;
            self.grad_cov[a] += g;
            self.grad_cloud[a] += g * s;
        }
    }
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
    /// Displacement of the octave at |N| = 1 (m): amplitude x wavelength.
    reach: f64,
}

/// The detail of one frame: octaves laid out on the domain, the edge widths.
#[derive(Debug, Clone)]
pub struct DetailNoise {
    octaves: Vec<Octave>,
    character: DetailCharacter,
    pub space: NoiseSpace,
    pub weights: [f64; 2],
    /// Half widths of the sharpened boundary (m): billowy and wispy.
    sharp: f64,
    soft: f64,
    /// Cloud water (density units) from which a particle counts fully as cloud.
    pub edge_water: f64,
    /// Means of one octave's billowy and wispy values over space, taken out so that the
    /// displacement neither erodes nor grows the cloud on average.
    means: [f64; 2],
    /// Some octave moves the surface (amplitude above 0): only then are the rest coordinates
    /// read.
    displaces: bool,
}

impl DetailNoise {
    /// `cloud_scale`: the density grid's units per kg/kg (`export.density_scale`).
    pub fn new(
        p: &DetailParams,
        domain: [f64; 3],
        voxel: f64,
        weights: [f64; 2],
        cloud_scale: f64,
    ) -> Self {
        let mut octaves = Vec::new();
        for o in 0..p.octaves {
            let lambda = p.scale / f64::from(1u32 << o);
            if lambda < MIN_WAVELENGTH_VOXELS * voxel {
                break;
            }
            let (cx, px) = lattice_for_extent(domain[0], lambda);
            let (cz, pz) = lattice_for_extent(domain[2], lambda);
            octaves.push(Octave {
                cx,
                px,
                cy: lambda,
                cz,
                pz,
                seed: pcg_hash(p.seed ^ 0x00de_7a11 ^ o),
                reach: p.amplitude * lambda,
            });
        }
        Self {
            character: p.character,
            space: p.space,
            weights,
            sharp: SHARP_VOXELS * voxel,
            soft: SOFT_VOXELS * voxel,
            edge_water: EDGE_WATER * cloud_scale,
            means: octave_means(),
            displaces: octaves.iter().any(|o| o.reach > 0.0),
            octaves,
        }
    }

    /// Whether the noise moves the surface; without it the boundary is only sharpened and the
    /// rest coordinates are not needed.
    pub fn displaces(&self) -> bool {
        self.displaces
    }

    /// Octaves in use (0: the voxels are too coarse for any: the boundary is still sharpened,
    /// but not displaced).
    pub fn octave_count(&self) -> usize {
        self.octaves.len()
    }

    /// Displacement (m) of the octaves at a point, with character `omega` (0 billowy, 1 wispy).
    pub fn noise(&self, p: [f64; 3], omega: f64) -> f64 {
        let mut n = 0.0;
        for o in &self.octaves {
            let v = value_noise3(p[0], p[2], p[1] / o.cy, o.cx, o.cz, o.px, o.pz, o.seed);
            let [billowy, wispy] = shapes(v);
            let billowy = billowy - self.means[0];
            let wispy = wispy - self.means[1];
            n += o.reach * (billowy + omega * (wispy - billowy));
        }
        n
    }

    /// The displacement of a voxel at world position `x` with rest coordinates `rest`, the two
    /// rest fields cross-faded.
    pub fn displacement(&self, x: [f64; 3], rest: [[f64; 3]; 2], omega: f64) -> f64 {
        if self.octaves.is_empty() {
            return 0.0;
        }
        let [wa, wb] = self.weights;
        let (ra, rb) = match self.space {
            NoiseSpace::Rest => (rest[0], rest[1]),
            NoiseSpace::World => (x, x),
        };
        let a = if wa > 0.0 { self.noise(ra, omega) } else { 0.0 };
        let b = if wb > 0.0 { self.noise(rb, omega) } else { 0.0 };
        // equal-power cross-fade at a constant angular rate: the blend turns from one field to
        // the other by the same angle every frame (the clock's weight is linear in time)
        let th = std::f64::consts::FRAC_PI_2 * wa / (wa + wb);
        th.sin() * a + th.cos() * b
    }

    /// The detailed density of a voxel from its kernel sums, at world position `x` with rest
    /// coordinates `rest`, before the frame's mass factor, and the voxel's weight m in that
    /// factor (the edge: 1 at the surface and outside, 0 in the core). `None` where the
    /// undetailed density is 0.
    pub fn edge(&self, s: &EdgeSums, x: [f64; 3], rest: [[f64; 3]; 2]) -> Option<(f64, f64)> {
        if !(s.dens > 0.0 && s.cov > 0.0 && s.cloud > 0.0) {
            return None;
        }
        let c = (s.cloud / s.cov).min(1.0);
        let h = s.cloud_h / s.cloud;
        let phi = h * distance_of_fraction(c);
        // the density of the cloud at the edge without the kernel's fade
        let q_in = s.dens / c;
        // grad c points into the cloud; across a plane boundary it is C'(0) / h = 1.23 / h.
        // The base is where it points up: its vertical part in units of 1 / h, so that a weak
        // gradient in a flat stretch of c (whose direction is the particles' noise) is not one
        let dcdy = (s.grad_cloud[1] * s.cov - s.cloud * s.grad_cov[1]) / (s.cov * s.cov);
        let base = smoothstep(0.25, 0.75, h * dcdy);
        let thin = 1.0 - smoothstep(self.edge_water, 6.0 * self.edge_water, q_in);
        let omega = match self.character {
            DetailCharacter::Wispy => 1.0,
            DetailCharacter::Billowy => base.max(thin),
        };
        // no billow out of a stray cloudy particle in clear air (c of one particle alone is
        // about 0.2): the displacement fades out where the cloud fraction does; and it stays
        // within 60% of the kernel radius (a soft limit), so that no crease reaches the core
        let reach = 0.6 * h;
        let d = if self.displaces {
            reach * (self.displacement(x, rest, omega) / reach).tanh() * smoothstep(0.02, 0.3, c)
        } else {
            // the same +0 the octaves of zero reach sum to, without evaluating them
            0.0
        };
        let w = self.sharp + omega * (self.soft - self.sharp);
        let value = q_in * smoothstep(-w, w, phi + d);
        let m = 1.0 - smoothstep(0.0, h, phi);
        Some((value, m))
    }
}

/// One octave's billowy 2|g| - 1 (round puffs, sharp creases) and wispy 2 (1 - |g|)^2 - 1
/// (thin ridges) for a value-noise sample v in [0, 1], g = 2 v - 1.
fn shapes(v: f64) -> [f64; 2] {
    let g = (2.0 * v - 1.0).abs();
    [2.0 * g - 1.0, 2.0 * (1.0 - g) * (1.0 - g) - 1.0]
}

/// Means of `shapes` over space for one octave of value noise, from 8^3 x 64 samples of a
/// fixed lattice (deterministic; the same for every octave, whose lattices differ only by seed
/// and cell size).
fn octave_means() -> [f64; 2] {
    let (mut b, mut w, mut n) = (0.0, 0.0, 0.0);
    for i in 0..32768u32 {
        let p = [
            (i & 31) as f64 * 0.618 + (i >> 10) as f64 * 0.071,
            ((i >> 5) & 31) as f64 * 0.414 + (i >> 10) as f64 * 0.133,
            (i >> 10) as f64 * 0.732,
        ];
        let v = value_noise3(
            p[0],
            p[2],
            p[1],
            1.0,
            1.0,
            64,
            64,
            pcg_hash(0x5eed ^ (i >> 12)),
        );
        let [sb, sw] = shapes(v);
        b += sb;
        w += sw;
        n += 1.0;
    }
    [b / n, w / n]
}

/// Cubic smoothstep from 0 at `a` to 1 at `b`.
pub fn smoothstep(a: f64, b: f64, x: f64) -> f64 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The cloud fraction at signed distance u h (u in [-1, 1], positive inside) from a plane
/// boundary between cloud and clear air: the poly6 kernel (h^2 - r^2)^3 integrated over the
/// cloudy half space, whose profile across the plane is (h^2 - s^2)^4 (the kernel integrated
/// over a disc of the plane), normalised: 1/2 + 315/256 (u - 4u^3/3 + 6u^5/5 - 4u^7/7 + u^9/9).
pub fn plane_fraction(u: f64) -> f64 {
    let u = u.clamp(-1.0, 1.0);
    let u2 = u * u;
    let p = u * (1.0 + u2 * (-4.0 / 3.0 + u2 * (6.0 / 5.0 + u2 * (-4.0 / 7.0 + u2 / 9.0))));
    0.5 + 315.0 / 256.0 * p
}

/// The signed distance u (kernel radii, -1 to 1) from a plane boundary at which the cloud
/// fraction is `c`: `plane_fraction`'s inverse; exactly 1 where the fraction is 1 (the core)
/// and -1 where it is 0 (or not a number). Newton's method on the fraction, whose slope is
/// 315/256 (1 - u^2)^4, kept inside a bracket that bisects wherever a step would leave it: 1 to
/// 6 evaluations (4 on average over c) to 1e-13 or to the fraction's rounding, where a plain
/// bisection took 44 (it was most of the splat's time with the detail).
pub fn distance_of_fraction(c: f64) -> f64 {
    if c >= 1.0 {
        return 1.0;
    }
    if c <= 0.0 || c.is_nan() {
        return -1.0;
    }
    let (mut lo, mut hi) = (-1.0f64, 1.0f64);
    let mut u = fraction_guess(c);
    for _ in 0..64 {
        let f = plane_fraction(u) - c;
        if f.abs() <= 2.0 * f64::EPSILON {
            // the fraction is c to its rounding: in the flat tails no u does better
            return u;
        }
        if f < 0.0 {
            lo = u;
        } else {
            hi = u;
        }
        let slope = 315.0 / 256.0 * (1.0 - u * u).powi(4);
        let newton = u - f / slope;
        let next = if (lo..=hi).contains(&newton) {
            newton
        } else {
            0.5 * (lo + hi)
        };
        if (next - u).abs() <= 1e-13 {
            return next;
        }
        u = next;
    }
    u
}

/// A first guess at `plane_fraction`'s inverse: near the middle its Taylor inverse, in the
/// tails (a fraction e from 0 or 1) the leading term e = 315/256 16/5 (1 - |u|)^5.
fn fraction_guess(c: f64) -> f64 {
    let y = (c - 0.5) * 256.0 / 315.0;
    let e = c.min(1.0 - c);
    if e > 0.12 {
        // P(u) = u - 4u^3/3 + ... = y, inverted to third order
        y + 4.0 / 3.0 * y * y * y
    } else {
        let s = (e / (315.0 / 256.0 * 16.0 / 5.0)).powf(0.2);
        (1.0 - s).copysign(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(character: DetailCharacter) -> DetailParams {
        DetailParams {
            scale: 100.0,
            amplitude: 0.25,
            octaves: 3,
            character,
            seed: 7,
            space: NoiseSpace::Rest,
        }
    }

    #[test]
    fn plane_fraction_runs_from_clear_to_cloud_and_inverts() {
        assert!(plane_fraction(-1.0).abs() < 1e-15);
        assert!((plane_fraction(1.0) - 1.0).abs() < 1e-12);
        assert!((plane_fraction(0.0) - 0.5).abs() < 1e-15);
        // symmetric: what the fade puts outside the plane it takes from inside
        for u in [0.1, 0.37, 0.8] {
            assert!((plane_fraction(u) + plane_fraction(-u) - 1.0).abs() < 1e-12);
        }
        for u in [-0.9, -0.3, 0.0, 0.25, 0.7] {
            assert!(
                (distance_of_fraction(plane_fraction(u)) - u).abs() < 1e-9,
                "{u}"
            );
        }
        assert_eq!(distance_of_fraction(1.0), 1.0);
        assert_eq!(distance_of_fraction(0.0), -1.0);
        assert_eq!(distance_of_fraction(f64::NAN), -1.0);
    }

    /// The inverse by bisection to the last bit: what `distance_of_fraction` replaces.
    fn bisected(c: f64) -> f64 {
        let (mut lo, mut hi) = (-1.0f64, 1.0f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if plane_fraction(mid) < c {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    #[test]
    fn newton_inverse_matches_bisection_across_the_fraction_and_its_tails() {
        let mut worst = 0.0f64;
        let tails = (1..=15).flat_map(|k| {
            let e = 10f64.powi(-k);
            [e, 1.0 - e, 3.0 * e, 1.0 - 3.0 * e]
        });
        for c in (1..20000).map(|i| i as f64 / 20000.0).chain(tails) {
            let (u, b) = (distance_of_fraction(c), bisected(c));
            // in the tails the fraction is flat to the last bit over a span of u: compare
            // there by the fraction each gives
            let du = (u - b).abs();
            let dc = (plane_fraction(u) - c).abs();
            assert!(du < 1e-10 || dc < 4.0 * f64::EPSILON, "c {c}: {u} vs {b}");
            worst = worst.max(du.min(dc));
        }
        eprintln!("worst {worst:e}");
    }

    #[test]
    fn noise_is_bounded_tiles_and_skips_aliasing_octaves() {
        let dom = [800.0, 400.0, 800.0];
        for omega in [0.0, 1.0] {
            let d = DetailNoise::new(
                &params(DetailCharacter::Billowy),
                dom,
                5.0,
                [1.0, 0.0],
                1000.0,
            );
            assert_eq!(d.octave_count(), 3);
            // at most amplitude x (100 + 50 + 25) m
            let bound = 0.25 * 175.0;
            let (mut lo, mut hi) = (f64::MAX, f64::MIN);
            for k in 0..3000 {
                let p = [
                    k as f64 * 7.31 % 800.0,
                    k as f64 * 3.7 % 400.0,
                    k as f64 * 11.9 % 800.0,
                ];
                let n = d.noise(p, omega);
                assert!(n.abs() <= bound + 1e-9);
                let m = d.noise([p[0] + 800.0, p[1], p[2] - 800.0], omega);
                assert!((n - m).abs() < 1e-9);
                lo = lo.min(n);
                hi = hi.max(n);
            }
            assert!(hi - lo > 0.4 * bound, "omega {omega}: {lo}..{hi}");
        }
        // 100, 50, 25 m octaves at 12.5 m voxels: 100 and 50 are 4 voxels or more; at 30 m
        // none
        let p = params(DetailCharacter::Billowy);
        let d = DetailNoise::new(&p, dom, 12.5, [1.0, 0.0], 1000.0);
        assert_eq!(d.octave_count(), 2);
        let d = DetailNoise::new(&p, dom, 30.0, [1.0, 0.0], 1000.0);
        assert_eq!(d.octave_count(), 0);
        assert_eq!(d.displacement([1.0; 3], [[1.0; 3]; 2], 0.0), 0.0);
    }

    #[test]
    fn world_space_ignores_the_rest_coordinate() {
        let mut p = params(DetailCharacter::Wispy);
        let dom = [800.0, 400.0, 800.0];
        let rest = DetailNoise::new(&p, dom, 5.0, [0.3, 0.7], 1000.0);
        p.space = NoiseSpace::World;
        let world = DetailNoise::new(&p, dom, 5.0, [0.3, 0.7], 1000.0);
        let x = [100.0, 50.0, 30.0];
        let r = [[140.0, 70.0, 10.0], [120.0, 60.0, 35.0]];
        assert_eq!(
            world.displacement(x, r, 0.5),
            world.displacement(x, [x, x], 0.5)
        );
        assert_eq!(
            rest.displacement(x, [x, x], 0.5),
            world.displacement(x, r, 0.5)
        );
        assert_ne!(rest.displacement(x, r, 0.5), world.displacement(x, r, 0.5));
    }

    /// The kernel sums at signed distance `s` (m) inside a plane boundary y = 0 (cloud above),
    /// for particles of radius `h` on a fine lattice with cloud water `q`.
    fn plane_sums(s: f64, h: f64, q: f64) -> EdgeSums {
        let mut out = EdgeSums::default();
        // a lattice whose layers lie half a step either side of the plane
        let step = h / 16.0;
        let n = (h / step).ceil() as i32 + 1;
        let j0 = (s / step).floor() as i32;
        let c = 315.0 / (64.0 * std::f64::consts::PI * h.powi(9)) * step.powi(3);
        for i in -n..=n {
            for j in j0 - n..=j0 + n {
                for k in -n..=n {
                    let xj = [i as f64 * step, (j as f64 + 0.5) * step, k as f64 * step];
                    let e = [-xj[0], s - xj[1], -xj[2]];
                    let r2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
                    if r2 >= h * h {
                        continue;
                    }
                    let d = h * h - r2;
                    let cloudy = xj[1] > 0.0; // cloud above the plane y = 0
                    let qq = if cloudy { q } else { 0.0 };
                    let sh = if cloudy { 1.0 } else { 0.0 };
                    out.add(c * d * d * d, -6.0 * c * d * d, e, qq, sh, h);
                }
            }
        }
        out
    }

    #[test]
    fn a_plane_boundary_is_sharpened_at_its_place_and_the_core_is_kept() {
        let h = 100.0;
        let mut p = params(DetailCharacter::Billowy);
        p.amplitude = 0.0; // no displacement: the sharpened edge alone
        let d = DetailNoise::new(&p, [800.0, 800.0, 800.0], 12.5, [1.0, 0.0], 1000.0);
        let q = 1.0;
        let at = |s: f64| {
            let e = plane_sums(s, h, q);
            let x = [0.0, s, 0.0];
            d.edge(&e, x, [x, x])
        };
        // deep inside: the undetailed density itself, weight 0 in the mass factor
        let e = plane_sums(1.2 * h, h, q);
        let (v, m) = at(1.2 * h).unwrap();
        assert!((v - e.dens).abs() < 1e-9 * e.dens && m == 0.0, "{v} {m}");
        // a voxel above the surface: nearly the cloud's own density; a voxel below: nearly 0
        let (above, _) = at(40.0).unwrap();
        let (below, mb) = at(-40.0).unwrap();
        assert!(
            above > 0.95 * q && below < 0.05 * q && mb == 1.0,
            "{above} {below}"
        );
        // the base of a cloud (it lies above the plane): the normal points down, so the edge
        // is the wispy one, 2.5 voxels each side
        let (mid, _) = at(0.0).unwrap();
        assert!((mid - 0.5 * q).abs() < 0.05, "{mid}");
        let (soft, _) = at(12.5).unwrap();
        assert!(soft < 0.9 * q && soft > 0.6 * q, "{soft}");
    }
}
