//! The particles' rest displacements smoothed over their neighbours, the first of the two passes
//! that give a voxel its rest coordinate (`export.detail.rest_smoothing`, docs/RENDERING.md).
//!
//! Each particle carries its displacement since the rest reset, x - rest. Particles shuffle
//! relative to the smooth flow, so that displacement is noisy at the particle scale; the detail
//! must follow the flow, not the shuffle. Per particle j:
//! D~_j = sum_i V_i W(x_j - x_i, s h_i) (x_i - rest_i) / sum_i V_i W(x_j - x_i, s h_i), the poly6
//! kernel W of radius s h_i (s = `rest_smoothing`), minimum image on the periodic axes. The splat
//! then interpolates D~ with the density kernel. Two passes (particles, then voxels) instead of one
//! wide kernel over the voxels: the voxel pass, the costly one at fine voxel sizes, stays at the
//! density kernel's support.
//!
//! Deterministic: each particle's sum visits the cells of a fixed grid in a fixed order and the
//! particles of a cell in index order, whatever the number of threads.
use super::detail::RestInput;
use super::{SplatParams, MIN_DENSITY_RATIO};
use crate::ground::{levels, ParticleState};
use rayon::prelude::*;
use std::collections::HashMap;

/// Displacements x - rest of field A and B (m, minimum image).
pub type Displacement = [[f64; 3]; 2];

struct Particle {
    x: [f64; 3],
    /// Squared radius of the smoothing kernel and V_i / radius^9 (poly6 up to a constant, which
    /// cancels in the Shepard mean).
    r2: f64,
    c: f64,
    disp: Displacement,
}

/// D~ for every particle of `state` that is `wanted`; `None` for the others and for particles
/// the splat skips (non-finite position, level beyond 60). Every particle is a neighbour.
pub fn smoothed_displacements(
    state: &ParticleState,
    rest: &RestInput,
    params: &SplatParams,
    wanted: &[bool],
) -> Vec<Option<Displacement>> {
    let codec = rest.codec;
    let s = params.rest_smoothing.max(1.0);
    let rho_min = MIN_DENSITY_RATIO * params.rest_density;
    let parts: Vec<Option<Particle>> = (0..state.len())
        .into_par_iter()
        .map(|j| {
            let p = state.pos[j];
            let x = [p[0] as f64, p[1] as f64, p[2] as f64];
            let level = state.info[j][1] as f64;
            if !x.iter().all(|v| v.is_finite()) || level > 60.0 {
                return None;
            }
            let r = levels::radius(params.h0, state.info[j][1]) * s;
            let rho = (state.density[j] as f64).max(rho_min);
            let rho = if rho.is_finite() { rho } else { rho_min };
            let vol = levels::mass(params.m0, state.info[j][1]) / rho;
            let q = rest.rest[j];
            Some(Particle {
                x: [0, 1, 2].map(|a| wrap(x[a], a, &codec)),
                r2: r * r,
                c: vol / r.powi(9),
                disp: [
                    codec.diff(x, codec.decode([q[0], q[1], q[2]])),
                    codec.diff(x, codec.decode([q[3], q[4], q[5]])),
                ],
            })
        })
        .collect();
    let cells = Cells::new(&parts, params.h0 * s, &codec);
    parts
        .par_iter()
        .zip(wanted)
        .map(|(p, &wanted)| {
            let p = p.as_ref().filter(|_| wanted)?;
            let mut cov = 0.0;
            let mut d = [[0.0f64; 3]; 2];
            cells.visit(p.x, |i| {
                let q = parts[i].as_ref().expect("binned particles are valid");
                let e = codec.diff(p.x, q.x);
                let r2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
                if r2 < q.r2 {
                    let w = q.c * (q.r2 - r2).powi(3);
                    cov += w;
                    for (dk, qk) in d.iter_mut().zip(&q.disp) {
                        for (x, v) in dk.iter_mut().zip(qk) {
                            *x += w * v;
                        }
                    }
                }
            });
            // cov > 0: the particle's own kernel holds it
            Some(d.map(|v| v.map(|x| x / cov)))
        })
        .collect()
}

fn wrap(x: f64, axis: usize, codec: &crate::ground::rest::RestCodec) -> f64 {
    if codec.periodic[axis] {
        x.rem_euclid(codec.size[axis])
    } else {
        x
    }
}

/// Cells at least the widest kernel radius wide (periodic axes: a whole number per period).
struct Cells {
    width: [f64; 3],
    dims: [i64; 3],
    periodic: [bool; 3],
    members: HashMap<[i64; 3], Vec<usize>>,
}

impl Cells {
    fn new(
        parts: &[Option<Particle>],
        radius: f64,
        codec: &crate::ground::rest::RestCodec,
    ) -> Self {
        let radius = radius.max(1e-6);
        let dims = [0, 1, 2].map(|a| {
            if codec.periodic[a] {
                ((codec.size[a] / radius).floor() as i64).max(1)
            } else {
                i64::MAX
            }
        });
        let width = [0, 1, 2].map(|a| {
            if codec.periodic[a] {
                codec.size[a] / dims[a] as f64
            } else {
                radius
            }
        });
        let mut cells = Self {
            width,
            dims,
            periodic: codec.periodic,
            members: HashMap::new(),
        };
        for (i, p) in parts.iter().enumerate() {
            if let Some(p) = p {
                let k = cells.key(p.x);
                cells.members.entry(k).or_default().push(i);
            }
        }
        cells
    }

    fn key(&self, x: [f64; 3]) -> [i64; 3] {
        [0, 1, 2].map(|a| {
            let c = (x[a] / self.width[a]).floor() as i64;
            if self.periodic[a] {
                c.clamp(0, self.dims[a] - 1)
            } else {
                c
            }
        })
    }

    /// Calls `f(i)` for every particle in the 27 cells around `x`, each cell once, in a fixed
    /// order.
    fn visit(&self, x: [f64; 3], mut f: impl FnMut(usize)) {
        let c = self.key(x);
        let mut keys = Vec::with_capacity(27);
        for dx in -1..=1i64 {
            for dy in -1..=1i64 {
                for dz in -1..=1i64 {
                    let mut k = [c[0] + dx, c[1] + dy, c[2] + dz];
                    for ((v, &periodic), &dim) in k.iter_mut().zip(&self.periodic).zip(&self.dims) {
                        if periodic {
                            *v = v.rem_euclid(dim);
                        }
                    }
                    keys.push(k);
                }
            }
        }
        // fewer than three cells along a periodic axis: the same cell comes up twice
        keys.sort_unstable();
        keys.dedup();
        for k in keys {
            if let Some(list) = self.members.get(&k) {
                list.iter().for_each(|&i| f(i));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ground::rest::RestCodec;

    fn lattice(n: usize, spacing: f32) -> ParticleState {
        let mut s = ParticleState::default();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let p = [i, j, k].map(|v| (v as f32 + 0.5) * spacing);
                    s.pos.push([p[0], p[1], p[2], 0.0]);
                    s.vel.push([0.0; 4]);
                    s.thermo.push([290.0, 0.0, 0.0, 0.0]);
                    s.info.push([s.info.len() as u32, 0]);
                    s.density.push(1.0);
                }
            }
        }
        s
    }

    fn params(size: f64) -> SplatParams {
        SplatParams {
            transform: SplatParams::domain_transform(0.5),
            h0: 2.0,
            m0: 1.0,
            rest_density: 1.0,
            domain_size: [size; 3],
            periodic: [true, true],
            threshold: 0.0,
            cloud_scale: 1.0,
            min_coverage: 0.0,
            fields: Default::default(),
            detail: None,
            rest_smoothing: 1.5,
        }
    }

    #[test]
    fn a_uniform_displacement_is_kept_and_a_shuffle_is_averaged_out() {
        let (n, d) = (8usize, 1.0f32);
        let size = n as f64 * d as f64;
        let state = lattice(n, d);
        let codec = RestCodec::new([size; 3], [true, true]);
        // every particle displaced by (0.5, 0.25, 0) since the reset, plus a +-0.2 shuffle in y
        let rest: Vec<[u16; 6]> = (0..state.len())
            .map(|j| {
                let p = state.pos[j];
                let wiggle = if j % 2 == 0 { 0.2 } else { -0.2 };
                let r = codec.encode([p[0] as f64 - 0.5, p[1] as f64 - 0.25 - wiggle, p[2] as f64]);
                [r[0], r[1], r[2], r[0], r[1], r[2]]
            })
            .collect();
        let input = RestInput {
            rest: &rest,
            codec,
            weights: [0.5, 0.5],
            dual: true,
        };
        let all = vec![true; state.len()];
        let out = smoothed_displacements(&state, &input, &params(size), &all);
        let q = 1.5 * size / 65535.0;
        for d in out.iter().map(|d| d.expect("valid particle")) {
            assert!((d[0][0] - 0.5).abs() < q, "{d:?}");
            assert!((d[0][2]).abs() < q, "{d:?}");
            // the alternating shuffle shrinks to a fraction of its 0.2 amplitude
            assert!((d[0][1] - 0.25).abs() < 0.1, "{d:?}");
            assert_eq!(d[0], d[1]);
        }
        // a particle not wanted gets none; the others the same, their neighbours unchanged
        let some: Vec<bool> = (0..state.len()).map(|j| j % 3 == 0).collect();
        let part = smoothed_displacements(&state, &input, &params(size), &some);
        for (j, d) in part.iter().enumerate() {
            assert_eq!(*d, if some[j] { out[j] } else { None }, "particle {j}");
        }
        // and the same with one thread
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        assert_eq!(
            one.install(|| smoothed_displacements(&state, &input, &params(size), &all)),
            out
        );
    }
}
