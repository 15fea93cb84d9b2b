//! GPU adaptive stage (split/merge) against its f64 mirror, and its invariants: exact mass,
//! water, disjoint merges, determinism, split-then-merge round trip, full capacity.
//! Runs on any wgpu adapter (lavapipe here): `XDG_RUNTIME_DIR=/tmp/xdg cargo test --test gpu_adaptive`.
#![allow(clippy::needless_range_loop)] // component loops over xyz read clearer indexed
mod harness;

use nimbus::config::AdaptiveConfig;
use nimbus::gpu::Context;
use nimbus::ground::ParticleState;
use nimbus::sim::adaptive::{level_mass_units, AdaptiveParams, AdaptiveReport, AdaptiveStage};
use nimbus::sim::buffers::ParticleBuffers;
use nimbus::sim::grid_params::GridParams;
use nimbus::sim::reference::adaptive::{self as mirror, RefParticles};
use nimbus::sim::reference::grid::build_cell_table;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const H0: f64 = 0.1;
/// Float tolerance GPU (f32) vs mirror (f64): positions within 1e-5 m in a 1 m box (f32 ulp
/// ~6e-8, a few ops, plus f32 cos/sin of the split direction); fields 1e-5 relative.
const TOL: f64 = 1e-5;

fn ctx() -> std::sync::Arc<Context> {
    harness::context()
}

/// The device side of a setup: particle buffers of its capacity and the stage bound to them.
struct Gpu {
    b: ParticleBuffers,
    stage: AdaptiveStage,
}

/// Host copy of the first `count` particles.
#[derive(Debug, Clone, PartialEq)]
struct Host {
    pos: Vec<[f32; 4]>,
    vel: Vec<[f32; 4]>,
    thermo: Vec<[f32; 4]>,
    info: Vec<[u32; 2]>,
}

impl Host {
    fn len(&self) -> usize {
        self.pos.len()
    }

    /// Permutes into cell order (the stage's input contract) and returns the cell table.
    fn sort(&mut self, g: &GridParams) -> Vec<u32> {
        let p64: Vec<[f64; 3]> = self
            .pos
            .iter()
            .map(|p| [0, 1, 2].map(|a| p[a] as f64))
            .collect();
        let (order, cell_start) = build_cell_table(g, &p64);
        let perm = |v: &mut Vec<[f32; 4]>| *v = order.iter().map(|&o| v[o as usize]).collect();
        perm(&mut self.pos);
        perm(&mut self.vel);
        perm(&mut self.thermo);
        self.info = order.iter().map(|&o| self.info[o as usize]).collect();
        cell_start
    }

    fn mass_units(&self, max_level: u32) -> u64 {
        self.info
            .iter()
            .map(|i| level_mass_units(i[1], max_level))
            .sum()
    }

    /// Sum of m (vapor + cloud), m in units of m0.
    fn water(&self) -> f64 {
        self.info
            .iter()
            .zip(&self.thermo)
            .map(|(i, t)| (-(i[1] as f64)).exp2() * (t[1] as f64 + t[2] as f64))
            .sum()
    }

    fn sorted_ids(&self) -> Vec<u32> {
        let mut ids: Vec<u32> = self.info.iter().map(|i| i[0]).collect();
        ids.sort();
        ids
    }
}

struct Setup {
    grid: GridParams,
    cfg: AdaptiveConfig,
    capacity: u32,
}

impl Setup {
    fn params(&self, count: u32, next_id: u32) -> AdaptiveParams {
        let mut p = AdaptiveParams::new(&self.cfg, H0, self.capacity);
        p.count = count;
        p.next_id = next_id;
        p
    }

    /// The scene of `host` (sorted into cell order) in the stage's input contract.
    fn scene(&self, host: &mut Host, next_id: u32) -> harness::Scene {
        let cell_start = host.sort(&self.grid);
        let n = host.len();
        harness::Scene {
            grid: self.grid,
            state: ParticleState {
                pos: host.pos.clone(),
                vel: host.vel.clone(),
                thermo: host.thermo.clone(),
                info: host.info.clone(),
                density: vec![0.0; n],
            },
            cell_start,
            boundary: (Vec::new(), vec![0; self.grid.table_len()]),
            capacity: self.capacity,
            next_id,
        }
    }

    /// Sorts `host`, runs the GPU stage, returns the live particles and the report.
    fn gpu(
        &self,
        ctx: &Context,
        gpu: &Gpu,
        host: &mut Host,
        next_id: u32,
    ) -> (Host, AdaptiveReport) {
        self.scene(host, next_id).write_into(ctx, &gpu.b);
        let rep = gpu.stage.run(ctx, &gpu.b.live).unwrap();
        let (out, live) = harness::read_particles(ctx, &gpu.b);
        assert_eq!((live.count, live.next_id), (rep.count, rep.next_id));
        let out = Host {
            pos: out.pos,
            vel: out.vel,
            thermo: out.thermo,
            info: out.info,
        };
        (out, rep)
    }

    /// The mirror on the same (already sorted) input.
    fn mirror(&self, host: &Host, next_id: u32) -> (RefParticles, AdaptiveReport) {
        let mut h = host.clone();
        let cell_start = h.sort(&self.grid);
        assert_eq!(&h, host, "mirror input must already be sorted");
        let mut p =
            RefParticles::from_f32(&h.pos, &h.vel, &h.thermo, &h.info, self.capacity as usize);
        let rep = mirror::run(
            &self.grid,
            &self.params(h.len() as u32, next_id),
            &cell_start,
            &mut p,
        );
        (p, rep)
    }

    /// Buffers of the setup's capacity and the stage over them.
    fn stage(&self, ctx: &Context) -> Gpu {
        let empty = Host {
            pos: vec![],
            vel: vec![],
            thermo: vec![],
            info: vec![],
        };
        let b = self.scene(&mut empty.clone(), 0).upload(ctx);
        let stage = AdaptiveStage::new(ctx, &self.cfg, &self.grid, H0, &b).unwrap();
        Gpu { b, stage }
    }
}

/// Random particles over a 10 x 6 x 11 cell grid (x and z not multiples of 3: the wrap slabs
/// get their own colours), levels 0..=3, cloud water chosen so that about a third want to
/// merge, a third to split.
fn random_host(rng: &mut ChaCha8Rng, n: usize, g: &GridParams) -> Host {
    let size = g.domain_size;
    let mut h = Host {
        pos: vec![],
        vel: vec![],
        thermo: vec![],
        info: vec![],
    };
    for id in 0..n as u32 {
        h.pos.push([
            rng.random::<f32>() * size[0],
            0.02 + rng.random::<f32>() * (size[1] - 0.04),
            rng.random::<f32>() * size[2],
            0.0,
        ]);
        h.vel
            .push([0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0f32)));
        let w = match rng.random_range(0..3) {
            0 => rng.random_range(0.0..5e-5f32),
            1 => rng.random_range(2e-4..4e-4f32),
            _ => rng.random_range(1e-3..5e-3f32),
        };
        h.thermo.push([
            rng.random_range(250.0..300.0f32),
            rng.random_range(0.0..0.02f32),
            w,
            0.0,
        ]);
        h.info.push([id, rng.random_range(0..=3)]);
    }
    h
}

fn setup(periodic: bool, capacity: u32) -> Setup {
    Setup {
        grid: GridParams::new([1.0, 0.65, 1.1], H0, periodic, periodic),
        // The random clouds of these tests are made for kc = 1000 (the default is tuned for
        // whole shots): pin it.
        cfg: AdaptiveConfig {
            enabled: true,
            kc: 1000.0,
            ..AdaptiveConfig::default()
        },
        capacity,
    }
}

fn assert_matches_mirror(
    s: &Setup,
    gpu: &Host,
    grep: &AdaptiveReport,
    m: &RefParticles,
    mrep: &AdaptiveReport,
) {
    assert_eq!(grep, mrep);
    let size = s.grid.domain_size;
    for i in 0..gpu.len() {
        assert_eq!(gpu.info[i], m.info[i], "info of slot {i}");
        for a in 0..3 {
            let mut d = (gpu.pos[i][a] as f64 - m.pos[i][a]).abs();
            if (a == 0 && s.grid.periodic_x()) || (a == 2 && s.grid.periodic_z()) {
                d = d.min(size[a] as f64 - d);
            }
            assert!(
                d < TOL,
                "pos of slot {i}: {:?} vs {:?}",
                gpu.pos[i],
                m.pos[i]
            );
        }
        for a in 0..4 {
            let close = |x: f32, y: f64| (x as f64 - y).abs() <= TOL * (1.0 + y.abs());
            assert!(close(gpu.vel[i][a], m.vel[i][a]), "vel of slot {i}");
            assert!(
                close(gpu.thermo[i][a], m.thermo[i][a]),
                "thermo of slot {i}: {:?} vs {:?}",
                gpu.thermo[i],
                m.thermo[i]
            );
        }
    }
}

#[test]
fn gpu_matches_mirror_on_random_inputs() {
    let ctx = ctx();
    for (seed, periodic) in [(1u64, true), (2, false), (3, true)] {
        let s = setup(periodic, 4000);
        let stage = s.stage(&ctx);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut host = random_host(&mut rng, 2000, &s.grid);
        let mut next_id = 2000;
        // Two rounds: the second starts from the GPU's output (re-sorted).
        for round in 0..2 {
            let (gpu, grep) = s.gpu(&ctx, &stage, &mut host, next_id);
            let (m, mrep) = s.mirror(&host, next_id);
            assert!(
                grep.merges > 20 && grep.splits > 20,
                "seed {seed} round {round}: {grep:?}"
            );
            assert_matches_mirror(&s, &gpu, &grep, &m, &mrep);
            next_id = grep.next_id;
            host = gpu;
            // Fresh cloud water for the next round, so it has merges and splits again.
            for t in &mut host.thermo {
                t[2] = match rng.random_range(0..3) {
                    0 => rng.random_range(0.0..5e-5f32),
                    1 => rng.random_range(2e-4..4e-4f32),
                    _ => rng.random_range(1e-3..5e-3f32),
                };
            }
        }
    }
}

#[test]
fn mass_exact_and_water_conserved_over_many_rounds() {
    let ctx = ctx();
    let s = setup(true, 6000);
    let stage = s.stage(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut host = random_host(&mut rng, 2500, &s.grid);
    let max_level = s.cfg.max_level;
    let mass0 = host.mass_units(max_level);
    let water0 = host.water();
    let mut next_id = host.len() as u32;
    let (mut splits, mut merges) = (0, 0);
    for round in 0..25 {
        let (out, rep) = s.gpu(&ctx, &stage, &mut host, next_id);
        assert_eq!(rep.mass_units, mass0, "round {round}");
        assert_eq!(out.mass_units(max_level), mass0, "round {round}");
        let per_level: Vec<u32> = (0..=max_level)
            .map(|l| out.info.iter().filter(|i| i[1] == l).count() as u32)
            .collect();
        assert_eq!(rep.per_level, per_level);
        let ids = out.sorted_ids();
        assert!(
            ids.windows(2).all(|w| w[0] < w[1]),
            "duplicate ids in round {round}"
        );
        assert!(ids.iter().all(|&id| id < rep.next_id));
        let water = out.water();
        assert!(
            (water - water0).abs() <= 1e-6 * water0,
            "round {round}: water {water} vs {water0}"
        );
        splits += rep.splits;
        merges += rep.merges;
        next_id = rep.next_id;
        // New cloud water per particle with vapour + cloud kept: the marks change, water not.
        host = out;
        for t in &mut host.thermo {
            let total = t[1] + t[2];
            let w: f32 = match rng.random_range(0..3) {
                0 => 0.0,
                1 => 3e-4,
                _ => 4e-3,
            };
            let w = w.min(total);
            t[2] = w;
            t[1] = total - w;
        }
        // Some drift so neighbourhoods change between rounds.
        for p in &mut host.pos {
            for (a, lim) in [(0, 1.0f32), (1, 0.65), (2, 1.1)] {
                p[a] = (p[a] + rng.random_range(-0.01..0.01f32)).clamp(0.0, lim - 1e-4);
            }
        }
    }
    assert!(
        splits > 500 && merges > 500,
        "splits {splits} merges {merges}"
    );
}

/// Every particle at level 2 wants to merge, packed densely: each particle takes part in at
/// most one merge (checked by ids and by the averaged velocities), and repeated runs give
/// byte-identical results.
#[test]
fn dense_cluster_merges_are_disjoint_and_repeatable() {
    let ctx = ctx();
    let mut s = setup(true, 3000);
    s.cfg.min_distance = 0.0;
    let stage = s.stage(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let n = 1500;
    let mut host = Host {
        pos: (0..n)
            .map(|_| {
                [
                    0.4 + 0.25 * rng.random::<f32>(),
                    0.2 + 0.25 * rng.random::<f32>(),
                    0.4 + 0.25 * rng.random::<f32>(),
                    0.0,
                ]
            })
            .collect(),
        // Distinct random velocities identify the partners of each merge.
        vel: (0..n)
            .map(|_| [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0f32)))
            .collect(),
        thermo: (0..n).map(|_| [280.0, 0.01, 0.0, 0.0]).collect(),
        info: (0..n as u32).map(|id| [id, 2]).collect(),
    };
    host.sort(&s.grid);
    let input = host.clone();
    let (a, rep_a) = s.gpu(&ctx, &stage, &mut host.clone(), n as u32);
    let (b, rep_b) = s.gpu(&ctx, &stage, &mut host.clone(), n as u32);
    assert_eq!(a, b, "runs differ");
    assert_eq!(rep_a.count, rep_b.count);
    assert!(rep_a.merges as usize > n / 4, "{rep_a:?}");
    assert_eq!(rep_a.count as usize, n - rep_a.merges as usize);

    let by_id = |id: u32| input.info.iter().position(|i| i[0] == id).unwrap();
    let out_ids = a.sorted_ids();
    assert!(out_ids.windows(2).all(|w| w[0] < w[1]), "duplicate ids");
    let vanished: Vec<u32> = input
        .sorted_ids()
        .into_iter()
        .filter(|id| out_ids.binary_search(id).is_err())
        .collect();
    assert_eq!(vanished.len(), rep_a.merges as usize);
    let mut used = vec![false; vanished.len()];
    let mut products = 0;
    for (k, inf) in a.info.iter().enumerate() {
        let i = by_id(inf[0]);
        if inf[1] == 2 {
            // Untouched particle.
            assert_eq!(a.vel[k], input.vel[i]);
            assert_eq!(a.pos[k], input.pos[i]);
            continue;
        }
        assert_eq!(inf[1], 1);
        products += 1;
        // The partner: a vanished particle with v_j = 2 v - v_i and a larger id.
        let want: Vec<f32> = (0..3)
            .map(|c| 2.0 * a.vel[k][c] - input.vel[i][c])
            .collect();
        let hits: Vec<usize> = vanished
            .iter()
            .enumerate()
            .filter(|(_, &id)| {
                let v = input.vel[by_id(id)];
                (0..3).all(|c| (v[c] - want[c]).abs() < 1e-5)
            })
            .map(|(x, _)| x)
            .collect();
        assert_eq!(hits.len(), 1, "product {} has no unique partner", inf[0]);
        assert!(
            !used[hits[0]],
            "particle {} merged twice",
            vanished[hits[0]]
        );
        assert!(vanished[hits[0]] > inf[0]);
        used[hits[0]] = true;
        let j = by_id(vanished[hits[0]]);
        for c in 0..3 {
            let mid = 0.5 * (input.pos[i][c] + input.pos[j][c]);
            assert!((a.pos[k][c] - mid).abs() < 1e-6);
        }
    }
    assert_eq!(products, rep_a.merges);
    assert!(used.iter().all(|&u| u));
    // And the mirror pairs them the same way.
    let (m, mrep) = s.mirror(&input, n as u32);
    assert_matches_mirror(&s, &a, &rep_a, &m, &mrep);
}

/// An isolated particle splits into two children, which merge back into the original.
#[test]
fn split_then_merge_restores_isolated_particle() {
    let ctx = ctx();
    for (x, id, level) in [
        ([0.43f32, 0.31, 0.57], 7u32, 0u32),
        ([0.999, 0.2, 0.001], 123, 2),
    ] {
        let mut s = setup(true, 8);
        s.cfg.split_threshold = -1.0;
        s.cfg.merge_threshold = -2.0;
        let stage_split = s.stage(&ctx);
        let orig = Host {
            pos: vec![[x[0], x[1], x[2], 0.0]],
            vel: vec![[0.3, -0.2, 0.1, 0.0]],
            thermo: vec![[281.5, 0.012, 0.003, 0.0]],
            info: vec![[id, level]],
        };
        let (split, rep) = s.gpu(&ctx, &stage_split, &mut orig.clone(), 1000);
        assert_eq!((rep.splits, rep.count, rep.next_id), (1, 2, 1001));
        assert_eq!(split.info, vec![[id, level + 1], [1000, level + 1]]);
        s.cfg.split_threshold = 2.0;
        s.cfg.merge_threshold = 1.5;
        let stage_merge = s.stage(&ctx);
        let (merged, rep) = s.gpu(&ctx, &stage_merge, &mut split.clone(), 1001);
        assert_eq!((rep.merges, rep.count), (1, 1));
        assert_eq!(merged.info, orig.info);
        assert_eq!(merged.vel, orig.vel);
        let e = 1.0 - (-1000.0f32 * 0.003).exp();
        assert_eq!(&merged.thermo[0][..3], &orig.thermo[0][..3]);
        assert!((merged.thermo[0][3] - e).abs() < 1e-6);
        for a in 0..3 {
            assert!(
                (merged.pos[0][a] - orig.pos[0][a]).abs() < 1e-6,
                "{:?} vs {:?}",
                merged.pos,
                orig.pos
            );
        }
    }
}

/// Every particle wants to split but the capacity has room for a few: the splits of the
/// highest scan ranks are skipped and counted, the count stops at the capacity.
#[test]
fn full_capacity_skips_and_counts_splits() {
    let ctx = ctx();
    let n = 60;
    for capacity in [60u32, 70, 115] {
        let s = setup(true, capacity);
        let stage = s.stage(&ctx);
        // Isolated particles (0.15 m apart), all with dense cloud.
        let mut host = Host {
            pos: (0..n)
                .map(|k| {
                    [
                        0.05 + 0.15 * (k % 6) as f32,
                        0.1 + 0.15 * ((k / 6) % 3) as f32,
                        0.05 + 0.3 * (k / 18) as f32,
                        0.0,
                    ]
                })
                .collect(),
            vel: vec![[0.0; 4]; n],
            thermo: vec![[280.0, 0.01, 0.01, 0.0]; n],
            info: (0..n as u32).map(|id| [id, 0]).collect(),
        };
        host.sort(&s.grid);
        let input = host.clone();
        let (out, rep) = s.gpu(&ctx, &stage, &mut host, 500);
        let room = capacity - n as u32;
        assert_eq!(rep.splits, room);
        assert_eq!(rep.skipped_splits, n as u32 - room);
        assert_eq!(rep.count, capacity);
        assert_eq!(rep.next_id, 500 + room);
        // The first `room` slots split (scan ranks 0..room), the rest kept their level.
        for k in 0..n {
            assert_eq!(out.info[k][1], (k < room as usize) as u32, "slot {k}");
        }
        for k in n..capacity as usize {
            assert_eq!(out.info[k], [500 + (k - n) as u32, 1]);
        }
        assert_eq!(rep.mass_units, input.mass_units(3));
        let (m, mrep) = s.mirror(&input, 500);
        assert_matches_mirror(&s, &out, &rep, &m, &mrep);
    }
}

/// 300 particles in one cell, all marked: a single merge thread would run past lavapipe's
/// 65535 loop iterations per invocation; the workgroup shares the neighbourhood scans, so every
/// particle pairs (as in the mirror) instead of the invocation stopping part-way through.
#[test]
fn crowded_cell_merges_completely() {
    let ctx = ctx();
    let mut s = setup(true, 400);
    s.cfg.min_distance = 0.0;
    let stage = s.stage(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let n = 300;
    let mut host = Host {
        pos: (0..n)
            .map(|_| {
                [
                    0.41 + 0.05 * rng.random::<f32>(),
                    0.21 + 0.05 * rng.random::<f32>(),
                    0.41 + 0.05 * rng.random::<f32>(),
                    0.0,
                ]
            })
            .collect(),
        vel: (0..n)
            .map(|_| [0, 1, 2, 3].map(|_| rng.random_range(-1.0..1.0f32)))
            .collect(),
        thermo: vec![[280.0, 0.01, 0.0, 0.0]; n],
        info: (0..n as u32).map(|id| [id, 2]).collect(),
    };
    host.sort(&s.grid);
    let input = host.clone();
    let (out, rep) = s.gpu(&ctx, &stage, &mut host, n as u32);
    assert_eq!((rep.merges, rep.count), (150, 150), "{rep:?}");
    assert_eq!(rep.per_level, vec![0, 150, 0, 0]);
    let (m, mrep) = s.mirror(&input, n as u32);
    assert_matches_mirror(&s, &out, &rep, &m, &mrep);
}

/// No particles: a clean no-op with an all-zero report, and count > capacity is an error.
#[test]
fn empty_input_and_bad_count() {
    let ctx = ctx();
    let s = setup(true, 16);
    let stage = s.stage(&ctx);
    let mut empty = Host {
        pos: vec![],
        vel: vec![],
        thermo: vec![],
        info: vec![],
    };
    let (out, rep) = s.gpu(&ctx, &stage, &mut empty, 3);
    assert_eq!(out.len(), 0);
    assert_eq!(
        (
            rep.count,
            rep.splits,
            rep.merges,
            rep.mass_units,
            rep.next_id
        ),
        (0, 0, 0, 0, 3)
    );
    assert_eq!(rep.per_level, vec![0; 4]);
    // more particles than the capacity: refused before anything runs
    let mut crowded = random_host(&mut ChaCha8Rng::seed_from_u64(1), 17, &s.grid);
    let scene = s.scene(&mut crowded, 0);
    assert!(ParticleBuffers::new(&ctx, &scene.state, 16, &scene.grid, &scene.boundary, 0).is_err());
}
