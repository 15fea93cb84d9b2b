//! Splat: partition of unity on a lattice, periodic continuity, determinism, brute-force check.
use nimbus::ground::ParticleState;
use nimbus::ground::SparseGrid;
use nimbus::sim::reference::common::{min_image, poly6};
use nimbus::splat::{splat, SplatFields, SplatParams};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const RHO0: f64 = 1.2;

fn params(size: [f64; 3], d: f64, voxel: f64, periodic: [bool; 2]) -> SplatParams {
    SplatParams {
        transform: SplatParams::domain_transform(voxel),
        h0: 2.0 * d,
        m0: RHO0 * d * d * d,
        rest_density: RHO0,
        domain_size: size,
        periodic,
        threshold: 0.0,
        cloud_scale: 1.0,
        min_coverage: 1e-3,
        fields: SplatFields::default(),
        detail: None,
        rest_smoothing: 1.0,
    }
}

/// A lattice of spacing d filling `size` (first particle at d/2), rho = rho0, level 0.
fn lattice(size: [f64; 3], d: f64, cloud: impl Fn([f64; 3]) -> f32) -> ParticleState {
    let n = size.map(|s| (s / d).round() as usize);
    let mut st = ParticleState::default();
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                let p = [i, j, k].map(|v| (v as f64 + 0.5) * d);
                st.pos.push([p[0] as f32, p[1] as f32, p[2] as f32, 0.0]);
                st.vel.push([1.0, -2.0, 0.5, 0.0]);
                st.thermo.push([290.0, 0.01, cloud(p), 0.0]);
                st.info.push([st.info.len() as u32, 0]);
                st.density.push(RHO0 as f32);
            }
        }
    }
    st
}

fn random_state(n: usize, size: [f64; 3], seed: u64) -> ParticleState {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut st = ParticleState::default();
    for i in 0..n {
        let p: [f64; 3] = std::array::from_fn(|a| rng.random_range(0.0..size[a]));
        st.pos.push([p[0] as f32, p[1] as f32, p[2] as f32, 0.0]);
        st.vel
            .push(std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
        st.thermo.push([
            rng.random_range(270.0..300.0),
            rng.random_range(0.0..0.02),
            if rng.random_bool(0.5) {
                rng.random_range(0.0..0.01)
            } else {
                0.0
            },
            0.0,
        ]);
        st.info.push([i as u32, rng.random_range(0..3)]);
        st.density
            .push(rng.random_range(0.8..1.6) as f32 * RHO0 as f32);
    }
    st
}

#[test]
fn uniform_lattice_is_a_partition_of_unity() {
    // Periodic in x and z, so only the walls in y have an edge: inside (a kernel radius away from
    // the floor and ceiling) sum_j (m/rho) W = 1 within 2% (lattice sum of poly6 at h = 2d deviates
    // by at most 1.4%), so density = cloud content w.
    let d = 1.0;
    let size = [16.0, 16.0, 16.0];
    let w = 0.004f32;
    let st = lattice(size, d, |_| w);
    let p = params(size, d, 0.5, [true, true]);
    let g = splat(&st, &p).unwrap();
    let dens = g.density.unwrap();
    let temp = g.temperature.unwrap();
    let mut checked = 0;
    for leaf in &dens.leaves {
        for n in 0..512 {
            let ijk = [n >> 6, (n >> 3) & 7, n & 7].map(|v| v as i32);
            let idx = [0, 1, 2].map(|a| leaf.origin[a] + ijk[a]);
            let y = p.transform.index_to_world(idx.map(|v| v as f64))[1];
            if y > 2.0 * d + 0.01 && y < size[1] - 2.0 * d - 0.01 {
                assert!(leaf.is_active(n));
                let ratio = leaf.values[n] as f64 / w as f64;
                assert!(
                    (ratio - 1.0).abs() < 0.02,
                    "sum (m/rho) W = {ratio} at {idx:?}"
                );
                // Shepard temperature of a uniform field is exact.
                assert!((temp.get(idx) - 290.0).abs() < 1e-3);
                checked += 1;
            }
        }
    }
    // 32 x 32 x 32 voxels, of which y in (2, 14): 24 rows.
    assert_eq!(checked, 32 * 24 * 32);
    // Every voxel of the periodic extent exists: no hole at the x/z faces.
    let (lo, hi) = dens.active_bbox().unwrap();
    assert_eq!((lo[0], hi[0], lo[2], hi[2]), (0, 31, 0, 31));
    assert!(lo[1] >= 0 && hi[1] <= 31);
}

#[test]
fn periodic_wrap_is_continuous_across_x_faces() {
    // A cloud blob centred on the x = 0 face: the splat must be mirror-symmetric about it, i.e.
    // voxel i and voxel N-1-i agree, and the last and first columns are neighbours in value.
    let d = 1.0;
    let size = [16.0, 8.0, 8.0];
    let st = lattice(size, d, |p| {
        let dx = p[0].min(size[0] - p[0]);
        if dx < 3.0 {
            0.01
        } else {
            0.0
        }
    });
    let p = params(size, d, 1.0, [true, true]);
    let dens = splat(&st, &p).unwrap().density.unwrap();
    let n = 16;
    for j in 0..8 {
        for k in 0..8 {
            for i in 0..n / 2 {
                let a = dens.get([i, j, k]);
                let b = dens.get([n - 1 - i, j, k]);
                assert!(
                    (a - b).abs() <= 1e-6 * a.abs().max(1e-9),
                    "{i},{j},{k}: {a} vs {b}"
                );
            }
            // Across the face the field is as smooth as inside it.
            let jump = (dens.get([0, j, k]) - dens.get([n - 1, j, k])).abs();
            assert!(jump <= 1e-7);
            if (2..6).contains(&j) {
                assert!(dens.get([0, j, k]) > 0.009);
            }
        }
    }
    // Without periodicity the face voxels only see half the blob.
    let p2 = params(size, d, 1.0, [false, true]);
    let open = splat(&st, &p2).unwrap().density.unwrap();
    assert!(open.get([0, 4, 4]) < 0.9 * dens.get([0, 4, 4]));
}

fn grid_bytes(g: &SparseGrid<f32>) -> Vec<u8> {
    let mut out = Vec::new();
    for l in &g.leaves {
        for o in l.origin {
            out.extend(o.to_le_bytes());
        }
        for m in l.mask {
            out.extend(m.to_le_bytes());
        }
        for v in l.values.iter() {
            out.extend(v.to_bits().to_le_bytes());
        }
    }
    out
}

#[test]
fn splat_is_identical_with_one_and_two_threads() {
    let size = [12.0, 10.0, 14.0];
    let st = random_state(3000, size, 7);
    let p = params(size, 0.5, 0.4, [true, true]);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| splat(&st, &p).unwrap())
    };
    let a = run(1);
    let b = run(2);
    let c = run(2);
    for (x, y) in [(&a, &b), (&b, &c)] {
        for (ga, gb) in [
            (&x.density, &y.density),
            (&x.temperature, &y.temperature),
            (&x.vapor, &y.vapor),
        ] {
            assert_eq!(
                grid_bytes(ga.as_ref().unwrap()),
                grid_bytes(gb.as_ref().unwrap())
            );
        }
        assert_eq!(x.velocity, y.velocity);
    }
    // Leaves sorted, unique, none empty.
    let g = a.density.unwrap();
    assert!(g.leaves.windows(2).all(|w| w[0].origin < w[1].origin));
    assert!(g.leaves.iter().all(|l| l.active_count() > 0));
}

#[test]
fn voxels_match_brute_force_sums() {
    let size = [10.0, 8.0, 9.0];
    let st = random_state(800, size, 11);
    let mut p = params(size, 0.6, 0.5, [true, true]);
    p.threshold = 1e-7;
    let g = splat(&st, &p).unwrap();
    let (dens, temp, vap, vel) = (
        g.density.unwrap(),
        g.temperature.unwrap(),
        g.vapor.unwrap(),
        g.velocity.unwrap(),
    );
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let dims = [20, 16, 18];
    let mut active_seen = 0;
    for _ in 0..60 {
        let ijk: [i32; 3] = std::array::from_fn(|a| rng.random_range(0..dims[a]));
        let x = p.transform.index_to_world(ijk.map(|v| v as f64));
        let (mut cov, mut sd, mut sv, mut st_, mut su) = (0.0, 0.0, 0.0, 0.0, [0.0; 3]);
        for j in 0..st.len() {
            let l = st.info[j][1] as f64;
            let h = p.h0 * 2f64.powf(-l / 3.0);
            let m = p.m0 * 2f64.powf(-l);
            let vol = m / st.density[j] as f64;
            let q = st.pos[j];
            let dd = min_image([0, 1, 2].map(|a| x[a] - q[a] as f64), size, [true, true]);
            let w = vol * poly6(dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2], h);
            cov += w;
            sd += w * st.thermo[j][2] as f64;
            sv += w * st.thermo[j][1] as f64;
            st_ += w * st.thermo[j][0] as f64;
            for (acc, u) in su.iter_mut().zip(st.vel[j]) {
                *acc += w * u as f64;
            }
        }
        let close = |a: f32, b: f64| (a as f64 - b).abs() <= 1e-5 * b.abs() + 1e-9;
        if sd >= p.threshold && sd > 0.0 {
            assert!(
                close(dens.get(ijk), sd),
                "density {ijk:?}: {} vs {sd}",
                dens.get(ijk)
            );
            active_seen += 1;
        } else {
            assert_eq!(dens.get(ijk), 0.0);
        }
        assert!(close(
            vap.get(ijk),
            if sv >= p.threshold { sv } else { 0.0 }
        ));
        if cov >= p.min_coverage {
            assert!(close(temp.get(ijk), st_ / cov), "temperature {ijk:?}");
            let u = vel.get(ijk);
            for c in 0..3 {
                assert!((u[c] as f64 - su[c] / cov).abs() < 1e-5);
            }
        } else {
            assert_eq!(temp.get(ijk), 0.0);
        }
    }
    assert!(
        active_seen > 10,
        "too few active voxels sampled: {active_seen}"
    );
}

#[test]
fn only_touched_blocks_are_allocated() {
    // One particle in a big domain: at most 2x2x2 leaves, and nothing when its cloud is 0 and
    // only density is asked for.
    let size = [200.0, 100.0, 200.0];
    let mut st = ParticleState::default();
    st.pos.push([100.0, 50.0, 100.0, 0.0]);
    st.vel.push([0.0; 4]);
    st.thermo.push([290.0, 0.0, 0.5, 0.0]);
    st.info.push([0, 0]);
    st.density.push(RHO0 as f32);
    let p = params(size, 1.0, 1.0, [true, true]);
    let g = splat(&st, &p).unwrap();
    let dens = g.density.unwrap();
    assert!(!dens.leaves.is_empty() && dens.leaves.len() <= 8);
    assert!(g.stats.leaves <= 8);
    st.thermo[0][2] = 0.0;
    let mut p2 = p.clone();
    p2.fields = SplatFields {
        density: true,
        temperature: false,
        vapor: false,
        velocity: false,
        rest: false,
    };
    let g2 = splat(&st, &p2).unwrap();
    assert!(g2.density.unwrap().leaves.is_empty());
    assert!(g2.temperature.is_none() && g2.velocity.is_none());
}

#[test]
fn bad_parameters_are_errors_not_panics() {
    let size = [10.0, 10.0, 10.0];
    let st = lattice(size, 1.0, |_| 0.1);
    let mut p = params(size, 1.0, 3.0, [true, true]);
    let e = splat(&st, &p).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("divide"), "{e}");
    p.transform.voxel_size = 0.0;
    assert!(splat(&st, &p).is_err());
    let p = params(size, 1.0, 1.0, [true, true]);
    let mut short = st.clone();
    short.density.pop();
    assert_eq!(splat(&short, &p).unwrap_err().exit_code(), 2);
}

mod detail {
    use super::*;
    use nimbus::config::DetailCharacter;
    use nimbus::ground::rest::{RestCodec, RestFrame};
    use nimbus::splat::detail::NoiseSpace;
    use nimbus::splat::{splat_with_rest, DetailParams, RestInput};

    const SIZE: [f64; 3] = [24.0, 16.0, 24.0];
    const VOXEL: f64 = 0.25;

    /// A ball of cloud in the middle of a periodic box of spacing 1, moved by `shift`.
    fn ball(shift: [f64; 3]) -> ParticleState {
        let mut st = lattice(SIZE, 1.0, |p| {
            let r = ((p[0] - 12.0).powi(2) + (p[1] - 8.0).powi(2) + (p[2] - 12.0).powi(2)).sqrt();
            (0.01 * (1.0 - r / 5.0).max(0.0)) as f32
        });
        for p in &mut st.pos {
            for a in 0..3 {
                p[a] += shift[a] as f32;
            }
        }
        st
    }

    fn codec() -> RestCodec {
        RestCodec::new(SIZE, [true, true])
    }

    /// Rest positions where the unshifted ball's particles are.
    fn rest() -> RestFrame {
        ball([0.0; 3])
            .pos
            .iter()
            .map(|p| {
                let q = codec().encode([p[0] as f64, p[1] as f64, p[2] as f64]);
                [q[0], q[1], q[2], q[0], q[1], q[2]]
            })
            .collect()
    }

    fn params(space: Option<NoiseSpace>) -> SplatParams {
        let mut p = super::params(SIZE, 1.0, VOXEL, [true, true]);
        p.fields = SplatFields {
            density: true,
            temperature: false,
            vapor: false,
            velocity: false,
            rest: true,
        };
        p.detail = space.map(|space| DetailParams {
            scale: 1.6,
            amplitude: 0.6,
            octaves: 2,
            character: DetailCharacter::Billowy,
            seed: 3,
            space,
        });
        p
    }

    fn run(st: &ParticleState, rest: &RestFrame, p: &SplatParams) -> nimbus::splat::SplatGrids {
        let input = RestInput {
            rest,
            codec: codec(),
            weights: [0.25, 0.75],
            dual: true,
        };
        splat_with_rest(st, p, Some(input)).unwrap()
    }

    fn sum(g: &SparseGrid<f32>) -> f64 {
        g.leaves
            .iter()
            .flat_map(|l| {
                (0..512)
                    .filter(|&n| l.is_active(n))
                    .map(|n| l.values[n] as f64)
            })
            .sum()
    }

    /// With the density alone, the clear air whose kernels reach no leaf of the cloud is left
    /// out of the rest smoothing and the binning; the density grid is the same bytes as when
    /// every particle is splatted (the rest grids ask for all of them).
    #[test]
    fn the_density_alone_skips_the_clear_air_and_gives_the_same_grid() {
        let st = ball([0.0; 3]);
        let rest = rest();
        let every = run(&st, &rest, &params(Some(NoiseSpace::Rest)));
        let mut p = params(Some(NoiseSpace::Rest));
        p.fields.rest = false;
        let alone = run(&st, &rest, &p);
        assert!(alone.rest.is_none());
        assert_eq!(
            grid_bytes(alone.density.as_ref().unwrap()),
            grid_bytes(every.density.as_ref().unwrap())
        );
        // a ball of radius 5 in a 24 x 16 x 24 box: most of the air is far from it
        assert!(
            alone.stats.sources * 2 < every.stats.sources,
            "{} of {} sources",
            alone.stats.sources,
            every.stats.sources
        );
    }

    #[test]
    fn detail_keeps_the_mass_adds_structure_and_moves_with_the_rest_frame() {
        let st = ball([0.0; 3]);
        let rest = rest();
        let plain = run(&st, &rest, &params(None)).density.unwrap();
        let detailed = run(&st, &rest, &params(Some(NoiseSpace::Rest)));
        let d = detailed.density.as_ref().unwrap();
        let (s0, s1) = (sum(&plain), sum(d));
        assert!((s1 / s0 - 1.0).abs() < 1e-3, "mass {s1} vs {s0}");
        // the detail acts at the surface: the edge (under a third of the ball's peak density)
        // changes by tens of percent, the core (over 80% of it) keeps its density
        let peak = plain
            .leaves
            .iter()
            .flat_map(|l| l.values.iter())
            .fold(0.0f32, |m, &v| m.max(v)) as f64;
        let (mut edge, mut core) = ([0.0f64; 2], [0.0f64; 2]);
        for l in &plain.leaves {
            for n in 0..512 {
                let ijk = [0, 1, 2].map(|a| {
                    l.origin[a] + [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32][a]
                });
                let (a, b) = (l.values[n] as f64, d.get(ijk) as f64);
                let acc = if a > 0.8 * peak {
                    &mut core
                } else if a > 0.0 && a < peak / 3.0 {
                    &mut edge
                } else {
                    continue;
                };
                acc[0] += (a - b) * (a - b);
                acc[1] += a * a;
            }
        }
        let (edge, core) = ((edge[0] / edge[1]).sqrt(), (core[0] / core[1]).sqrt());
        eprintln!("relative change: edge {edge}, core {core}");
        assert!(edge > 0.2, "edge changed by {edge}");
        assert!(core < 0.05, "core changed by {core}");
        // the rest grids: fresh rest positions are the voxel centres
        let r = detailed.rest.as_ref().unwrap();
        assert!(detailed.rest2.is_some());
        let c = [48, 32, 48];
        let x = r.transform.index_to_world(c.map(|v| v as f64));
        let v = r.get(c);
        for a in 0..3 {
            assert!((v[a] as f64 - x[a]).abs() < 1e-3, "{v:?} vs {x:?}");
        }

        // Deterministic, whatever the threads.
        let p = params(Some(NoiseSpace::Rest));
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| run(&st, &rest, &p));
        assert_eq!(grid_bytes(one.density.as_ref().unwrap()), grid_bytes(d));

        // Moved by a whole number of voxels with the rest positions kept, the detailed cloud is
        // the same cloud, moved; world-space noise is not.
        let shift = [1.0, 0.5, -0.75];
        let moved = ball(shift);
        let s = shift.map(|x| (x / VOXEL) as i32);
        for (space, sticks) in [(NoiseSpace::Rest, true), (NoiseSpace::World, false)] {
            let a = run(&st, &rest, &params(Some(space))).density.unwrap();
            let b = run(&moved, &rest, &params(Some(space))).density.unwrap();
            let (mut worst, mut max) = (0.0f64, 0.0f64);
            for l in &a.leaves {
                for n in 0..512 {
                    let ijk = [0, 1, 2].map(|k| {
                        l.origin[k] + [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32][k]
                    });
                    let there = [ijk[0] + s[0], ijk[1] + s[1], ijk[2] + s[2]];
                    let (x, y) = (l.values[n] as f64, b.get(there) as f64);
                    worst = worst.max((x - y).abs());
                    max = max.max(x);
                }
            }
            if sticks {
                assert!(
                    worst < 1e-3 * max,
                    "{space:?}: moved detail differs by {worst} (max {max})"
                );
            } else {
                assert!(
                    worst > 0.1 * max,
                    "{space:?}: world noise moved with the cloud ({worst})"
                );
            }
        }

        // Without rest positions the detail is refused, not skipped.
        assert!(splat(&st, &params(Some(NoiseSpace::Rest))).is_err());
        // And off, the rest input changes nothing.
        let mut p0 = super::params(SIZE, 1.0, VOXEL, [true, true]);
        p0.fields.velocity = false;
        let without = splat(&st, &p0).unwrap();
        let with = run(&st, &rest, &p0);
        assert_eq!(
            grid_bytes(without.density.as_ref().unwrap()),
            grid_bytes(with.density.as_ref().unwrap())
        );
        assert!(with.rest.is_none());
    }

    /// At amplitude 0 the detail only sharpens: the rest positions are not read, so a
    /// scrambled rest frame and other blend weights give the same bytes (at 0.6 they do not);
    /// the mass is kept and the edge is cut to fewer voxels than the kernel's fade.
    #[test]
    fn sharpening_alone_reads_no_rest_positions() {
        let st = ball([0.0; 3]);
        let scrambled: RestFrame = rest().into_iter().rev().collect();
        let other = |p: &SplatParams| {
            let input = RestInput {
                rest: &scrambled,
                codec: codec(),
                weights: [0.9, 0.1],
                dual: false,
            };
            splat_with_rest(&st, p, Some(input))
                .unwrap()
                .density
                .unwrap()
        };
        let mut p = params(Some(NoiseSpace::Rest));
        p.fields.rest = false;
        let displaced = run(&st, &rest(), &p).density.unwrap();
        assert_ne!(grid_bytes(&displaced), grid_bytes(&other(&p)));

        p.detail.as_mut().unwrap().amplitude = 0.0;
        let sharp = run(&st, &rest(), &p).density.unwrap();
        assert_eq!(grid_bytes(&sharp), grid_bytes(&other(&p)));
        let mut plain = p.clone();
        plain.detail = None;
        let plain = run(&st, &rest(), &plain).density.unwrap();
        assert!((sum(&sharp) / sum(&plain) - 1.0).abs() < 1e-3);
        assert!(
            sharp.active_voxel_count() * 10 < plain.active_voxel_count() * 9,
            "{} active voxels sharpened, {} plain",
            sharp.active_voxel_count(),
            plain.active_voxel_count()
        );
    }
}
