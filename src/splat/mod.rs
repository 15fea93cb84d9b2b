//! CPU splatting (rayon) of particle fields onto sparse 8^3-leaf grids.
//!
//! SPH interpolation at voxel centres with the simulation's poly6 kernel and each particle's own
//! radius (h_j = h0 2^(-l/3), m_j = m0 2^(-l), volume V_j = m_j / rho_j):
//! - `density` (cloud water) = sum_j cloud_j V_j W(x - x_j, h_j), `vapor` likewise: plain SPH sums,
//!   so they fade to 0 at the edge of the particles, as a fog volume should;
//! - `temperature` and `vel` are Shepard-normalised, sum_j T_j V_j W / sum_j V_j W: a weighted mean
//!   of the particles' values, which does not fade towards 0 K at the edge where the kernel sum
//!   drops below 1. They are active where the coverage sum_j V_j W reaches `min_coverage`.
//!
//! Index space: voxel centres on integer points (`GridTransform`). Periodic axes (x, z) must hold
//! a whole number N of voxels per period; particles close to a periodic face also contribute,
//! through image copies shifted by ±N voxels (the paper's image particles), to voxels on the other
//! side. Output voxels are those whose centres lie in the domain `[0, size]` (on a periodic axis
//! N of them, the face at `size` being the image of the face at 0).
//!
//! Determinism: particles (and their images) are binned to the leaf that holds them by a stable
//! sort; every output leaf is computed by one thread, which visits the bins of its neighbour leaves
//! in a fixed order and the particles of a bin in index order, accumulating in f64. The output is
//! therefore byte-identical whatever the number of threads.
//!
//! With the frame's rest positions (`splat_with_rest`, `sim::rest`): the `rest` grids are the
//! voxel centres less the displacement since each rest reset, first smoothed over the particles
//! (`rest_smooth`) and then interpolated like `vel` (active where `vel` is), and `export.detail` modulates the density by noise at that rest coordinate
//! (`detail`), renormalised to the undetailed total once per frame.
pub mod detail;
pub mod rest_smooth;
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_DIM, LEAF_VOXELS};
pub use detail::{DetailParams, RestInput};

use crate::config::{Axis, ShotConfig};
use crate::error::{Error, Result};
use crate::ground::{levels, ParticleState};
use rayon::prelude::*;

/// Which grids to produce.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SplatFields {
    pub density: bool,
    pub temperature: bool,
    pub vapor: bool,
    pub velocity: bool,
    /// The rest-position grids (`sim::rest`; needs a `RestInput`).
    pub rest: bool,
}

impl Default for SplatFields {
    fn default() -> Self {
        Self {
            density: true,
            temperature: true,
            vapor: true,
            velocity: true,
            rest: false,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct SplatParams {
    /// One transform for the whole shot (voxel size and the world position of voxel (0,0,0)).
    pub transform: GridTransform,
    /// Level-0 kernel radius and mass.
    pub h0: f64,
    pub m0: f64,
    /// rho0: densities are clamped to >= `MIN_DENSITY_RATIO * rest_density` (guards V = m/rho).
    pub rest_density: f64,
    /// Domain box `[0, size]` (metres).
    pub domain_size: [f64; 3],
    /// Periodic [x, z].
    pub periodic: [bool; 2],
    /// `density` and `vapor` voxels below this stay inactive.
    pub threshold: f64,
    /// Multiplier of the cloud water (kg/kg) in the density grid (`export.density_scale`).
    pub cloud_scale: f64,
    /// `temperature` and `vel` voxels whose coverage sum_j V_j W is below this stay inactive.
    pub min_coverage: f64,
    pub fields: SplatFields,
    /// `export.detail` (needs a `RestInput`); `None`: off.
    pub detail: Option<DetailParams>,
    /// Radius of the rest-displacement kernel over the density kernel's (`export.detail.rest_smoothing`).
    pub rest_smoothing: f64,
}

/// An isolated particle's own SPH density is m W(0) ~ 0.2 rho0 for h = 2d, so this clamp only
/// catches zero, negative or garbage densities, never a real SPH value.
pub const MIN_DENSITY_RATIO: f64 = 0.05;
/// Largest kernel radius in voxels: beyond it one particle would touch thousands of leaves.
pub const MAX_RADIUS_VOXELS: f64 = 64.0;

impl SplatParams {
    /// Voxel centres at `(i + 1/2) * voxel_size`: voxel i covers `[i v, (i+1) v]` of the domain.
    pub fn domain_transform(voxel_size: f64) -> GridTransform {
        GridTransform {
            voxel_size,
            origin: [0.5 * voxel_size; 3],
        }
    }

    /// Parameters of a shot: h0 = kernel_ratio * d, and m0 the lattice cell's mass rho0 d^3
    /// (`ShotConfig::cell_mass`), so that V = m / rho is a particle's share of the box, d^3 at
    /// rest.
    pub fn from_config(cfg: &ShotConfig) -> Result<Self> {
        let p = Self {
            transform: Self::domain_transform(cfg.export.voxel_size),
            h0: cfg.domain.kernel_radius(),
            m0: cfg.cell_mass(),
            rest_density: cfg.solver.rest_density,
            domain_size: cfg.domain.size,
            periodic: [
                cfg.domain.periodic.contains(&Axis::X),
                cfg.domain.periodic.contains(&Axis::Z),
            ],
            threshold: cfg.export.threshold,
            cloud_scale: cfg.export.density_scale,
            min_coverage: 1.0e-3,
            fields: SplatFields {
                density: !cfg.export.grids.density.is_empty(),
                temperature: !cfg.export.grids.temperature.is_empty(),
                vapor: !cfg.export.grids.vapor.is_empty(),
                velocity: !cfg.export.grids.velocity.is_empty(),
                rest: !cfg.export.grids.rest.is_empty(),
            },
            detail: DetailParams::from_config(cfg),
            rest_smoothing: cfg.export.detail.rest_smoothing,
        };
        p.validate()?;
        Ok(p)
    }

    fn is_periodic(&self, axis: usize) -> bool {
        match axis {
            0 => self.periodic[0],
            2 => self.periodic[1],
            _ => false,
        }
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidInput(format!("splat: {m}")));
        let v = self.transform.voxel_size;
        if !(v.is_finite() && v > 0.0) {
            return bad(format!("voxel size must be > 0, got {v}"));
        }
        if !self.transform.origin.iter().all(|o| o.is_finite()) {
            return bad("grid origin must be finite".into());
        }
        for (name, x) in [
            ("h0", self.h0),
            ("m0", self.m0),
            ("rest density", self.rest_density),
        ] {
            if !(x.is_finite() && x > 0.0) {
                return bad(format!("{name} must be > 0, got {x}"));
            }
        }
        if !(self.threshold.is_finite() && self.threshold >= 0.0) {
            return bad(format!("threshold must be >= 0, got {}", self.threshold));
        }
        if !(self.min_coverage.is_finite() && self.min_coverage > 0.0) {
            return bad(format!(
                "min coverage must be > 0, got {}",
                self.min_coverage
            ));
        }
        if self.h0 / v > MAX_RADIUS_VOXELS {
            return bad(format!(
                "voxel size {v} is too small for the kernel radius {} (at most {MAX_RADIUS_VOXELS} voxels per radius)",
                self.h0
            ));
        }
        for a in 0..3 {
            let s = self.domain_size[a];
            if !(s.is_finite() && s > 0.0) {
                return bad(format!("domain size must be > 0, got {s}"));
            }
            if self.is_periodic(a) {
                let n = s / v;
                if (n - n.round()).abs() > 1e-6 * n.max(1.0) || n.round() < 1.0 {
                    return bad(format!(
                        "voxel size {v} must divide the periodic domain extent {s} (axis {})",
                        ["x", "y", "z"][a]
                    ));
                }
                if s < 2.0 * self.h0 {
                    return bad(format!(
                        "periodic extent {s} is smaller than two kernel radii ({})",
                        2.0 * self.h0
                    ));
                }
            }
        }
        Ok(())
    }

    /// Inclusive index range of the output voxels per axis and, for periodic axes, the period N.
    fn index_range(&self) -> ([i64; 3], [i64; 3], [Option<i64>; 3]) {
        let t = &self.transform;
        let mut lo = [0i64; 3];
        let mut hi = [0i64; 3];
        let mut period = [None; 3];
        for a in 0..3 {
            let eps = 1e-9;
            let first = ((0.0 - t.origin[a]) / t.voxel_size - eps).ceil() as i64;
            if self.is_periodic(a) {
                let n = (self.domain_size[a] / t.voxel_size).round() as i64;
                lo[a] = first;
                hi[a] = first + n - 1;
                period[a] = Some(n);
            } else {
                lo[a] = first;
                hi[a] = ((self.domain_size[a] - t.origin[a]) / t.voxel_size + eps).floor() as i64;
            }
        }
        (lo, hi, period)
    }
}

/// The grids of one frame; a field not requested is `None`.
#[derive(Debug, Clone, PartialEq)]
pub struct SplatGrids {
    pub density: Option<SparseGrid<f32>>,
    pub temperature: Option<SparseGrid<f32>>,
    pub vapor: Option<SparseGrid<f32>>,
    pub velocity: Option<SparseGrid<[f32; 3]>>,
    /// Rest positions of field A and, with dual rest fields, B (m, simulation frame).
    pub rest: Option<SparseGrid<[f32; 3]>>,
    pub rest2: Option<SparseGrid<[f32; 3]>>,
    pub stats: SplatStats,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SplatStats {
    /// Particles that contributed (finite position, inside the walled extent).
    pub particles: u64,
    /// Particles plus periodic images that reach a written leaf (with the density alone, those
    /// near cloud).
    pub sources: u64,
    /// Leaves allocated (touched by some kernel support).
    pub leaves: u64,
    /// Voxels evaluated: `leaves * 512`.
    pub voxels: u64,
}

/// One particle or periodic image, in index space.
#[derive(Debug, Clone, Copy)]
struct Source {
    key: [i32; 3],
    p: [f64; 3],
    /// Radius in voxels and the squared world radius.
    r: f64,
    h2: f64,
    /// V_j * poly6 normalisation: weight = c (h^2 - r^2)^3.
    c: f64,
    cloud: f64,
    /// Share of "cloud" in the detail's cloud fraction (`detail::cloud_share`) and the radius
    /// (m).
    share: f64,
    h: f64,
    vapor: f64,
    temp: f64,
    vel: [f64; 3],
    /// Displacement since the rest reset of field A and B, smoothed over the particles
    /// (`rest_smooth`), m.
    disp: rest_smooth::Displacement,
}

fn leaf_of(i: f64) -> i32 {
    (i / LEAF_DIM as f64).floor() as i32
}

/// Splats `state` onto the requested sparse grids (see the module docs for the formulas).
pub fn splat(state: &ParticleState, params: &SplatParams) -> Result<SplatGrids> {
    splat_with_rest(state, params, None)
}

/// `splat` with the frame's rest positions, which `export.detail` and the rest grids need.
pub fn splat_with_rest(
    state: &ParticleState,
    params: &SplatParams,
    rest: Option<RestInput>,
) -> Result<SplatGrids> {
    params.validate()?;
    let n = state.len();
    let wants_rest = params.fields.rest || params.detail.is_some();
    match rest {
        None if wants_rest => {
            return Err(Error::InvalidInput(
                "splat: export.detail and the rest grid need the particles' rest positions".into(),
            ))
        }
        Some(r) if r.rest.len() != n => {
            return Err(Error::InvalidInput(format!(
                "splat: {} rest positions for {n} particles",
                r.rest.len()
            )))
        }
        _ => {}
    }
    let f = params.fields;
    let t = params.transform;
    let v = t.voxel_size;
    let noise = params.detail.as_ref().map(|d| {
        // the blend weights matter only where the noise displaces, and then rest is given
        let weights = rest.map_or([1.0, 0.0], |r| r.weights);
        detail::DetailNoise::new(d, params.domain_size, v, weights, params.cloud_scale)
    });
    // The rest positions are read for the rest grids and for a displacing detail; a detail at
    // amplitude 0 only sharpens, from the kernel sums alone.
    let rest_used = f.rest || noise.as_ref().is_some_and(|n| n.displaces());
    let rest = if rest_used { rest } else { None };
    let need_vel = params.fields.velocity;
    if state.thermo.len() != n
        || state.info.len() != n
        || state.density.len() != n
        || (need_vel && state.vel.len() != n)
    {
        return Err(Error::InvalidInput(format!(
            "splat: particle arrays differ in length (pos {n}, vel {}, thermo {}, info {}, density {})",
            state.vel.len(),
            state.thermo.len(),
            state.info.len(),
            state.density.len()
        )));
    }
    let (lo, hi, period) = params.index_range();
    // Particles with zero cloud and vapor add nothing to those grids: skip them unless a
    // normalised field or the detail's cloud fraction needs every particle.
    let all = f.temperature || f.velocity || rest.is_some() || noise.is_some();
    let rho_min = MIN_DENSITY_RATIO * params.rest_density;

    let mut per_particle: Vec<Vec<Source>> = (0..n)
        .into_par_iter()
        .map(|j| {
            let th = state.thermo[j];
            let useful = all || (f.density && th[2] != 0.0) || (f.vapor && th[1] != 0.0);
            if !useful {
                return Vec::new();
            }
            let pw = state.pos[j];
            let mut world = [pw[0] as f64, pw[1] as f64, pw[2] as f64];
            if !world.iter().all(|x| x.is_finite()) {
                return Vec::new();
            }
            for a in [0, 2] {
                if params.is_periodic(a) {
                    world[a] = world[a].rem_euclid(params.domain_size[a]);
                }
            }
            let level = state.info[j][1] as f64;
            if level > 60.0 {
                // No simulation splits that deep; h^9 would underflow.
                return Vec::new();
            }
            let h = levels::radius(params.h0, state.info[j][1]);
            let m = levels::mass(params.m0, state.info[j][1]);
            let rho = (state.density[j] as f64).max(rho_min);
            let rho = if rho.is_finite() { rho } else { rho_min };
            let vol = m / rho;
            let c = vol * 315.0 / (64.0 * std::f64::consts::PI * h.powi(9));
            let r = h / v;
            let p = t.world_to_index(world);
            let vel = if need_vel {
                let u = state.vel[j];
                [u[0] as f64, u[1] as f64, u[2] as f64]
            } else {
                [0.0; 3]
            };
            // Shifts (in voxels) of the images whose support meets the output range.
            let mut shifts: [Vec<f64>; 3] = Default::default();
            for a in 0..3 {
                let ks: Vec<i64> = match period[a] {
                    Some(np) => {
                        let m = (r / np as f64).ceil() as i64 + 1;
                        (-m..=m).map(|k| k * np).collect()
                    }
                    None => vec![0],
                };
                for s in ks {
                    let q = p[a] + s as f64;
                    if q + r > lo[a] as f64 && q - r < hi[a] as f64 {
                        shifts[a].push(s as f64);
                    }
                }
            }
            let mut out = Vec::new();
            for &sx in &shifts[0] {
                for &sy in &shifts[1] {
                    for &sz in &shifts[2] {
                        let q = [p[0] + sx, p[1] + sy, p[2] + sz];
                        out.push(Source {
                            key: q.map(leaf_of),
                            p: q,
                            r,
                            h2: h * h,
                            c,
                            cloud: th[2] as f64 * params.cloud_scale,
                            share: detail::cloud_share(th[2] as f64, detail::EDGE_WATER),
                            h,
                            vapor: th[1] as f64,
                            temp: th[0] as f64,
                            vel,
                            disp: [[0.0; 3]; 2],
                        });
                    }
                }
            }
            out
        })
        .collect();
    let particles = per_particle.iter().filter(|s| !s.is_empty()).count() as u64;

    // Leaves touched by some support, clipped to the output range. When the density is the
    // only grid, only the supports of particles with cloud water can give a leaf a value (the
    // others still add to the sums of the leaves they reach: the detail's cloud fraction and
    // rest coordinate).
    let leaf_lo = lo.map(|x| leaf_of(x as f64));
    let leaf_hi = hi.map(|x| leaf_of(x as f64));
    // Leaves of the voxels within a support (a voxel exactly at distance h gets 0).
    let leaf_box = |s: &Source| {
        let a = [0, 1, 2].map(|k| leaf_of((s.p[k] - s.r).ceil()).max(leaf_lo[k]));
        let b = [0, 1, 2].map(|k| leaf_of((s.p[k] + s.r).floor()).min(leaf_hi[k]));
        (a, b)
    };
    let density_only = !(f.temperature || f.vapor || f.velocity || f.rest);
    let mut touched: Vec<[i32; 3]> = per_particle
        .par_iter()
        .flatten()
        .filter(|s| !density_only || s.cloud > 0.0)
        .flat_map_iter(|s| {
            let (a, b) = leaf_box(s);
            (a[0]..=b[0]).flat_map(move |x| {
                (a[1]..=b[1]).flat_map(move |y| (a[2]..=b[2]).map(move |z| [x, y, z]))
            })
        })
        .collect();
    touched.par_sort_unstable();
    touched.dedup();

    // With the density alone, a particle whose support meets no touched leaf adds nothing to
    // any voxel that is written: drop it before the rest smoothing and the binning, which
    // otherwise cost as much for the clear air as for the cloud.
    if density_only {
        per_particle.par_iter_mut().for_each(|list| {
            let reaches = list.iter().any(|s| {
                let (a, b) = leaf_box(s);
                (a[0]..=b[0]).any(|x| {
                    (a[1]..=b[1])
                        .any(|y| (a[2]..=b[2]).any(|z| touched.binary_search(&[x, y, z]).is_ok()))
                })
            });
            if !reaches {
                list.clear();
            }
        });
    }
    if let Some(r) = &rest {
        let wanted: Vec<bool> = per_particle.iter().map(|l| !l.is_empty()).collect();
        let smoothed = rest_smooth::smoothed_displacements(state, r, params, &wanted);
        per_particle
            .par_iter_mut()
            .zip(smoothed)
            .for_each(|(list, d)| {
                let disp = d.unwrap_or([[0.0; 3]; 2]);
                list.iter_mut().for_each(|s| s.disp = disp);
            });
    }
    let mut sources: Vec<Source> = per_particle.into_iter().flatten().collect();
    // Stable: within a bin, sources stay in (particle index, image) order.
    sources.par_sort_by_key(|s| s.key);

    // Bins: unique keys and their ranges in `sources`.
    let mut bin_keys: Vec<[i32; 3]> = Vec::new();
    let mut bin_start: Vec<usize> = Vec::new();
    for (i, s) in sources.iter().enumerate() {
        if bin_keys.last() != Some(&s.key) {
            bin_keys.push(s.key);
            bin_start.push(i);
        }
    }
    bin_start.push(sources.len());
    let max_r = sources.iter().map(|s| s.r).fold(0.0f64, f64::max);
    let reach = (max_r / LEAF_DIM as f64).ceil() as i32;

    let ctx = LeafCtx {
        sources: &sources,
        bin_keys: &bin_keys,
        bin_start: &bin_start,
        reach,
        lo,
        hi,
        voxel: v,
        params,
        rest: rest.is_some(),
        dual: rest.is_some_and(|r| r.dual),
        noise: noise.as_ref(),
    };
    let mut leaves: Vec<LeafOut> = touched.par_iter().map(|&k| ctx.compute(k)).collect();
    if noise.is_some() {
        // One factor per frame on the edge keeps the total: sums in leaf order
        // (deterministic).
        let (mut s0, mut s1, mut sm) = (0.0f64, 0.0f64, 0.0f64);
        for l in &leaves {
            if let Some(d) = &l.detailed {
                s0 += d.undetailed_sum;
                s1 += d.detailed_sum;
                sm += d.edge_sum;
            }
        }
        let k = edge_factor(s0, s1, sm);
        let thr = params.threshold;
        leaves.par_iter_mut().for_each(|l| {
            if let Some(d) = l.detailed.take() {
                l.density = leaf_from(d.origin, |n| {
                    let x = d.values[n] * (1.0 + k * d.edge[n]).max(0.0);
                    (x > 0.0 && x >= thr).then_some(x as f32)
                });
            }
        });
    }

    let stats = SplatStats {
        particles,
        sources: sources.len() as u64,
        leaves: touched.len() as u64,
        voxels: touched.len() as u64 * LEAF_VOXELS as u64,
    };
    let mut dens = Vec::new();
    let mut temp = Vec::new();
    let mut vap = Vec::new();
    let mut vel = Vec::new();
    let mut rest_a = Vec::new();
    let mut rest_b = Vec::new();
    for l in leaves {
        dens.extend(l.density);
        temp.extend(l.temperature);
        vap.extend(l.vapor);
        vel.extend(l.velocity);
        rest_a.extend(l.rest[0].clone());
        rest_b.extend(l.rest[1].clone());
    }
    let vec_grid = |name: &str, leaves| SparseGrid {
        name: name.into(),
        background: [0.0f32; 3],
        transform: t,
        leaves,
    };
    let rest_grids = f.rest && rest.is_some();
    let grid = |name: &str, leaves| SparseGrid {
        name: name.into(),
        background: 0.0f32,
        transform: t,
        leaves,
    };
    Ok(SplatGrids {
        density: f.density.then(|| grid("density", dens)),
        temperature: f.temperature.then(|| grid("temperature", temp)),
        vapor: f.vapor.then(|| grid("vapor", vap)),
        velocity: f.velocity.then(|| vec_grid("vel", vel)),
        rest: rest_grids.then(|| vec_grid("rest", rest_a)),
        rest2: (rest_grids && ctx.dual).then(|| vec_grid("rest2", rest_b)),
        stats,
    })
}

struct LeafCtx<'a> {
    sources: &'a [Source],
    bin_keys: &'a [[i32; 3]],
    bin_start: &'a [usize],
    reach: i32,
    lo: [i64; 3],
    hi: [i64; 3],
    voxel: f64,
    params: &'a SplatParams,
    /// Sources carry displacements to interpolate.
    rest: bool,
    /// The second rest field is in use (its grid is written).
    dual: bool,
    noise: Option<&'a detail::DetailNoise>,
}

struct LeafOut {
    density: Option<Leaf<f32>>,
    temperature: Option<Leaf<f32>>,
    vapor: Option<Leaf<f32>>,
    velocity: Option<Leaf<[f32; 3]>>,
    rest: [Option<Leaf<[f32; 3]>>; 2],
    /// With detail: the detailed density before the frame's normalisation and threshold.
    detailed: Option<Detailed>,
}

struct Detailed {
    origin: [i32; 3],
    values: Box<[f64; LEAF_VOXELS]>,
    /// Each voxel's weight in the frame's mass factor (`detail::DetailNoise::edge`).
    edge: Box<[f64; LEAF_VOXELS]>,
    /// Sum of the undetailed active values, of the detailed values, and of the detailed values
    /// times their edge weight.
    undetailed_sum: f64,
    detailed_sum: f64,
    edge_sum: f64,
}

/// k of the frame's mass factor 1 + k m: the detailed total (s1, of which sm weighted by m)
/// brought to the undetailed one (s0). 0 when there is no edge to scale.
pub fn edge_factor(s0: f64, s1: f64, sm: f64) -> f64 {
    if sm > 0.0 {
        (s0 - s1) / sm
    } else {
        0.0
    }
}

impl LeafCtx<'_> {
    fn compute(&self, key: [i32; 3]) -> LeafOut {
        let f = self.params.fields;
        let o = key.map(|k| k * LEAF_DIM);
        let mut cov = [0.0f64; LEAF_VOXELS];
        let mut dens = [0.0f64; LEAF_VOXELS];
        let mut vap = [0.0f64; LEAF_VOXELS];
        let mut tnum = [0.0f64; LEAF_VOXELS];
        let mut vnum = [[0.0f64; 3]; LEAF_VOXELS];
        let mut dnum = if self.rest {
            vec![[0.0f64; 6]; LEAF_VOXELS]
        } else {
            Vec::new()
        };
        let mut edge = if self.noise.is_some() {
            vec![detail::EdgeSums::default(); LEAF_VOXELS]
        } else {
            Vec::new()
        };
        // Voxels of this leaf inside the output range.
        let vlo = [0, 1, 2].map(|a| (o[a] as i64).max(self.lo[a]));
        let vhi = [0, 1, 2].map(|a| (o[a] as i64 + 7).min(self.hi[a]));
        let v2 = self.voxel * self.voxel;
        let r = self.reach;
        for dx in -r..=r {
            for dy in -r..=r {
                for dz in -r..=r {
                    let nk = [key[0] + dx, key[1] + dy, key[2] + dz];
                    let Ok(b) = self.bin_keys.binary_search(&nk) else {
                        continue;
                    };
                    for s in &self.sources[self.bin_start[b]..self.bin_start[b + 1]] {
                        let a = [0, 1, 2].map(|k| ((s.p[k] - s.r).ceil() as i64).max(vlo[k]));
                        let e = [0, 1, 2].map(|k| ((s.p[k] + s.r).floor() as i64).min(vhi[k]));
                        if a[0] > e[0] || a[1] > e[1] || a[2] > e[2] {
                            continue;
                        }
                        for x in a[0]..=e[0] {
                            let ddx = (x as f64 - s.p[0]) * (x as f64 - s.p[0]) * v2;
                            for y in a[1]..=e[1] {
                                let ddy = ddx + (y as f64 - s.p[1]) * (y as f64 - s.p[1]) * v2;
                                if ddy >= s.h2 {
                                    continue;
                                }
                                for z in a[2]..=e[2] {
                                    let r2 = ddy + (z as f64 - s.p[2]) * (z as f64 - s.p[2]) * v2;
                                    if r2 >= s.h2 {
                                        continue;
                                    }
                                    let n = Leaf::<f32>::offset(x as i32, y as i32, z as i32);
                                    let d = s.h2 - r2;
                                    let w = s.c * d * d * d;
                                    if let Some(es) = edge.get_mut(n) {
                                        let e = [
                                            (x as f64 - s.p[0]) * self.voxel,
                                            (y as f64 - s.p[1]) * self.voxel,
                                            (z as f64 - s.p[2]) * self.voxel,
                                        ];
                                        es.add(w, -6.0 * s.c * d * d, e, s.cloud, s.share, s.h);
                                    }
                                    if self.rest {
                                        let dn = &mut dnum[n];
                                        for a in 0..3 {
                                            dn[a] += w * s.disp[0][a];
                                            dn[3 + a] += w * s.disp[1][a];
                                        }
                                    }
                                    cov[n] += w;
                                    dens[n] += w * s.cloud;
                                    // only the grids written: with the detail every clear
                                    // particle near a cloud is a source of the density alone
                                    if f.vapor {
                                        vap[n] += w * s.vapor;
                                    }
                                    if f.temperature {
                                        tnum[n] += w * s.temp;
                                    }
                                    if f.velocity {
                                        for (acc, u) in vnum[n].iter_mut().zip(s.vel) {
                                            *acc += w * u;
                                        }
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        let thr = self.params.threshold;
        let minc = self.params.min_coverage;
        let plain = |acc: &[f64; LEAF_VOXELS]| {
            leaf_from(o, |n| {
                let x = acc[n];
                (x > 0.0 && x >= thr).then_some(x as f32)
            })
        };
        // Rest coordinates of voxel n: its centre less the interpolated displacement.
        let t = self.params.transform;
        let centre = |n: usize| {
            let l = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
            t.index_to_world([0, 1, 2].map(|a| (o[a] + l[a]) as f64))
        };
        let rest_of = |n: usize| {
            let x = centre(n);
            let c = cov[n];
            let Some(d) = dnum.get(n) else {
                // no rest positions read: the detail only sharpens and ignores them
                return (x, [x, x]);
            };
            let r = |k: usize| [0, 1, 2].map(|a| if c > 0.0 { x[a] - d[k + a] / c } else { x[a] });
            (x, [r(0), r(3)])
        };
        let rest_leaf = |k: usize| {
            leaf_from(o, |n| {
                (cov[n] >= minc).then(|| rest_of(n).1[k].map(|x| x as f32))
            })
        };
        let want_rest = self.rest && f.rest;
        let detailed = match (self.noise, f.density) {
            (Some(noise), true) => {
                let mut values = Box::new([0.0f64; LEAF_VOXELS]);
                let mut weights = Box::new([0.0f64; LEAF_VOXELS]);
                let (mut s0, mut s1, mut sm) = (0.0, 0.0, 0.0);
                for n in 0..LEAF_VOXELS {
                    let x = dens[n];
                    if x > 0.0 {
                        if x >= thr {
                            s0 += x;
                        }
                        let (c, r) = rest_of(n);
                        if let Some((y, m)) = noise.edge(&edge[n], c, r) {
                            values[n] = y;
                            weights[n] = m;
                            s1 += y;
                            sm += y * m;
                        }
                    }
                }
                Some(Detailed {
                    origin: o,
                    values,
                    edge: weights,
                    undetailed_sum: s0,
                    detailed_sum: s1,
                    edge_sum: sm,
                })
            }
            _ => None,
        };
        LeafOut {
            rest: [
                if want_rest { rest_leaf(0) } else { None },
                if want_rest && self.dual {
                    rest_leaf(1)
                } else {
                    None
                },
            ],
            detailed,
            density: if f.density { plain(&dens) } else { None },
            vapor: if f.vapor { plain(&vap) } else { None },
            temperature: if f.temperature {
                leaf_from(o, |n| (cov[n] >= minc).then(|| (tnum[n] / cov[n]) as f32))
            } else {
                None
            },
            velocity: if f.velocity {
                leaf_from(o, |n| {
                    (cov[n] >= minc).then(|| vnum[n].map(|u| (u / cov[n]) as f32))
                })
            } else {
                None
            },
        }
    }
}

/// A leaf whose voxel n holds `value(n)` where that is `Some` (active), the zero background
/// elsewhere; `None` when no voxel is active.
fn leaf_from<T: Copy + Default>(
    origin: [i32; 3],
    value: impl Fn(usize) -> Option<T>,
) -> Option<Leaf<T>> {
    let mut values = Box::new([T::default(); LEAF_VOXELS]);
    let mut mask = [0u64; 8];
    for n in 0..LEAF_VOXELS {
        if let Some(x) = value(n) {
            values[n] = x;
            mask[n / 64] |= 1 << (n % 64);
        }
    }
    mask.iter().any(|&w| w != 0).then_some(Leaf {
        origin,
        values,
        mask,
    })
}
