//! `nimbus bench pbf`: milliseconds per PBF substep and per phase, device bytes per particle.
//!
//! Two scenes: `periodic` (the box filled with a lattice, x/z periodic: the figures of
//! docs/PERFORMANCE.md "PBF") and `block` (a block of liquid at rest in a closed box, the scene
//! `tools/bench_pbf_vs_splishsplash.py` builds for SPlisHSPlasH too).
use crate::config::{GpuConfig, ShotConfig};
use crate::error::{Error, Result};
use crate::ground::{ParticleState, SimClock};
use crate::shot::Shot;
use crate::sim::Simulation;
use std::sync::Arc;

/// Which scene `bench pbf` times.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PbfScene {
    /// The whole box a lattice, x/z periodic, floor and ceiling walls.
    Periodic,
    /// A block of liquid in a closed box (no periodic axis), as SPlisHSPlasH's fluid block.
    Block,
}

/// What `bench pbf` runs; `None` fields take the scene's default.
#[derive(Debug, Clone, Copy)]
pub struct PbfBench {
    pub scene: PbfScene,
    /// Periodic: about this many particles (a cube). Block: the block is n x 0.8n x n with
    /// n = round((particles / 0.8)^(1/3)) (the harness makes SPlisHSPlasH's block the same).
    pub particles: usize,
    pub steps: u32,
    pub warmup: u32,
    /// Particle spacing d (m): periodic 1, block 0.05 (SPlisHSPlasH's radius 0.025).
    pub spacing: Option<f64>,
    /// h0 / d (2: ~33 neighbours in a disordered liquid, 27 on the lattice).
    pub kernel_ratio: f64,
    /// Density iterations per substep.
    pub iterations: u32,
    /// Fixed substep (s): periodic 0.02, block 0.002.
    pub dt: Option<f64>,
}

impl PbfBench {
    /// The defaults of `nimbus bench pbf`.
    pub fn new(particles: usize, steps: u32, warmup: u32) -> Self {
        Self {
            scene: PbfScene::Periodic,
            particles,
            steps,
            warmup,
            spacing: None,
            kernel_ratio: 2.0,
            iterations: 4,
            dt: None,
        }
    }
    fn spacing(&self) -> f64 {
        self.spacing.unwrap_or(match self.scene {
            PbfScene::Periodic => 1.0,
            PbfScene::Block => 0.05,
        })
    }
    fn dt(&self) -> f64 {
        self.dt.unwrap_or(match self.scene {
            PbfScene::Periodic => 0.02,
            PbfScene::Block => 0.002,
        })
    }
}

/// Particles per axis of the block scene's liquid: n x round(0.8 n) x n.
pub fn block_dims(particles: usize) -> [usize; 3] {
    let n = ((particles as f64 / 0.8).cbrt().round() as usize).max(2);
    [n, ((0.8 * n as f64).round() as usize).max(2), n]
}

/// The block scene's box in spacings: 1.6 x 1.5 x 1.2 the block (SPlisHSPlasH's anchor scene).
pub fn block_box(dims: [usize; 3]) -> [usize; 3] {
    let f = [1.6, 1.5, 1.2];
    [0, 1, 2].map(|a| (dims[a] as f64 * f[a]).round() as usize + 2)
}

/// The shot behind a bench run. Fixed dt (one substep per frame, no CFL substeps), and
/// `reference_step` = dt so that all `iterations` run in every substep.
pub fn bench_config(b: &PbfBench) -> Result<ShotConfig> {
    let d = b.spacing();
    let dt = b.dt();
    let (kr, it) = (b.kernel_ratio, b.iterations);
    // the export's voxels are the spacing (it writes nothing, but the shot is a valid one: a
    // voxel that divides the periodic extent)
    let output = format!(
        "output: {{frames: {{start: 0, end: 1}}, substeps: 1, max_substeps: 1, frame_seconds: {dt}}}\n\
         export: {{voxel_size: {d}}}"
    );
    let yaml = match b.scene {
        PbfScene::Periodic => {
            let side = (b.particles as f64).cbrt().round().max(4.0) * d;
            format!(
                "shot: bench\n{output}\n\
                 domain: {{size: [{side}, {side}, {side}], spacing: {d}, kernel_ratio: {kr}}}\n\
                 solver: {{gravity: 9.81, iterations: {it}, reference_step: {dt}}}\n"
            )
        }
        PbfScene::Block => {
            let bx = block_box(block_dims(b.particles)).map(|n| n as f64 * d);
            // What SPlisHSPlasH's PBF does: no s_corr, compression only (C = max(rho/rho0 - 1,
            // 0): a tolerance of 1 leaves all under-density alone), XSPH 0.01 per step, no
            // vorticity; no heating or buoyancy, so the thermodynamics do not move the liquid.
            format!(
                "shot: bench\n{output}\n\
                 domain: {{size: [{}, {}, {}], spacing: {d}, kernel_ratio: {kr}, periodic: []}}\n\
                 solver: {{gravity: 9.81, iterations: {it}, reference_step: {dt}, rest_density: 1000, \
                 scorr_k: 0, xsph: 0.01, expansion_tolerance: 1.0, vorticity: 0, max_speed: 100}}\n\
                 physics: {{heat_source: 0, heat_noise: false, buoyancy: 0, cloud_weight: 0, \
                 initial_speed: 0}}\n",
                bx[0], bx[1], bx[2]
            )
        }
    };
    serde_saphyr::from_str(&yaml).map_err(|e| Error::Config(format!("bench config: {e}")))
}

/// The block scene's liquid at rest: SPlisHSPlasH's fluid-block sampling (spacing d, the first
/// particle 2 d from the -x wall and the floor, centred in z).
pub fn block_state(cfg: &ShotConfig, particles: usize) -> ParticleState {
    let n = block_dims(particles);
    let d = cfg.domain.spacing;
    let z0 = 0.5 * cfg.domain.size[2] - 0.5 * (n[2] as f64 + 1.0) * d;
    let count = n[0] * n[1] * n[2];
    let mut s = ParticleState {
        pos: Vec::with_capacity(count),
        vel: vec![[0.0; 4]; count],
        thermo: Vec::with_capacity(count),
        info: Vec::with_capacity(count),
        density: vec![cfg.solver.rest_density as f32; count],
    };
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                let p = [
                    (i as f64 + 2.0) * d,
                    (j as f64 + 2.0) * d,
                    z0 + (k as f64 + 1.0) * d,
                ];
                s.info.push([s.pos.len() as u32, 0]);
                s.pos.push([p[0] as f32, p[1] as f32, p[2] as f32, 0.0]);
                s.thermo
                    .push(crate::sim::thermo::initial_thermo(&cfg.physics, p[1]));
            }
        }
    }
    s
}

/// Particles of the scene on `cfg`, without making them.
fn scene_count(cfg: &ShotConfig, b: &PbfBench) -> u64 {
    match b.scene {
        PbfScene::Periodic => crate::config::lattice_count(&cfg.domain) as u64,
        PbfScene::Block => block_dims(b.particles).iter().product::<usize>() as u64,
    }
}

/// Whether the device holds the scene on `cfg` (exit 4 with the limit and the largest count
/// that fits when it does not), before any particle is made.
fn check_scene(ctx: &crate::gpu::Context, cfg: &ShotConfig, b: &PbfBench) -> Result<()> {
    let shot = Shot::prepare(cfg.clone())?;
    let size = crate::sim::footprint::ShotSize::of(&shot, scene_count(cfg, b));
    crate::sim::footprint::check(ctx, &size, || None).map(|_| ())
}

/// The scene's simulation on `cfg` (the periodic box's lattice, or the block at rest).
fn scene_sim(ctx: &Arc<crate::gpu::Context>, cfg: &ShotConfig, b: &PbfBench) -> Result<Simulation> {
    let shot = Shot::prepare(cfg.clone())?;
    match b.scene {
        PbfScene::Periodic => Simulation::new(ctx.clone(), &shot),
        PbfScene::Block => {
            let state = block_state(cfg, b.particles);
            let clock = SimClock {
                next_id: state.len() as u32,
                ..Default::default()
            };
            Simulation::from_state(ctx.clone(), &shot, &state, clock)
        }
    }
}

/// Runs `steps` substeps after `warmup` (at least one: pipeline compilation, first grid build);
/// returns the figures as JSON. `pbf_step_ms` = pbf + grid + velocity (GPU timestamps when the
/// adapter has them, else host-timed phases, which add a wait per phase).
pub fn bench_pbf(b: &PbfBench) -> Result<serde_json::Value> {
    let cfg = bench_config(b)?;
    let ctx = Arc::new(crate::gpu::Context::new(&GpuConfig::default())?);
    // Both scenes checked before anything is computed: the bench's own (refused with exit 4
    // when the device cannot hold it) and the one with adaptivity that `with_adaptivity`
    // measures (reported as refused when only it does not fit).
    check_scene(&ctx, &cfg, b)?;
    let adaptive_cfg = with_adaptivity(&cfg);
    let adaptive_fits = check_scene(&ctx, &adaptive_cfg, b);
    if let Err(e) = &adaptive_fits {
        eprintln!("note: with adaptivity the scene does not fit this device: {e}");
    }
    let mut sim = scene_sim(&ctx, &cfg, b)?;
    if !ctx.timestamps {
        sim.set_timing(crate::sim::Timing::HostWaits);
    }
    for _ in 0..b.warmup.max(1) {
        sim.step_frame()?;
    }
    let steps = b.steps.max(1);
    let mut phases = std::collections::BTreeMap::<String, f64>::new();
    let t0 = std::time::Instant::now();
    let cpu0 = super::process_cpu_seconds();
    let mut last = None;
    for _ in 0..steps {
        let r = sim.step_frame()?;
        for (k, v) in r.phases.by_key() {
            *phases.entry(k).or_insert(0.0) += v;
        }
        last = Some(r);
    }
    let wall = t0.elapsed().as_secs_f64() * 1e3 / steps as f64;
    // CPU time of the whole process (lavapipe's threads included): steadier than wall clock on a
    // shared machine for comparing two builds
    let cpu = cpu0
        .zip(super::process_cpu_seconds())
        .map(|(a, b)| (b - a) * 1e3 / steps as f64);
    let n = sim.count();
    for v in phases.values_mut() {
        *v /= steps as f64;
    }
    let step: f64 = ["pbf", "grid", "velocity"]
        .iter()
        .map(|k| phases.get(*k).copied().unwrap_or(0.0))
        .sum();
    let diag = last.map(|r| r.diagnostics.to_map()).unwrap_or_default();
    let adaptive = match adaptive_fits {
        Ok(()) => adaptive_memory(&ctx, &adaptive_cfg, b)?,
        Err(e) => serde_json::json!({ "fits": false, "refused": e.to_string() }),
    };
    Ok(serde_json::json!({
        "scene": match b.scene { PbfScene::Periodic => "periodic", PbfScene::Block => "block" },
        "particles": n,
        "boundary_particles": sim.boundary_count(),
        "spacing": cfg.domain.spacing,
        "kernel_ratio": cfg.domain.kernel_ratio,
        "domain": cfg.domain.size,
        "dt": b.dt(),
        "steps": steps,
        "warmup": b.warmup.max(1),
        // reference_step = dt: every substep runs all of them
        "iterations": cfg.solver.iterations,
        "adapter": ctx.adapter_name(),
        "adapter_info": ctx.describe(),
        "gpu_timestamps": ctx.timestamps,
        "pbf_step_ms": step,
        "ms_per_substep_wall": wall,
        "cpu_ms_per_substep": cpu,
        "phase_ms": phases,
        "device_bytes": sim.device_bytes(),
        "device_bytes_per_particle": sim.device_bytes() as f64 / n as f64,
        "with_adaptivity": adaptive,
        "diagnostics": diag,
    }))
}

/// The bench's shot with smoothing and adaptivity on.
fn with_adaptivity(cfg: &ShotConfig) -> ShotConfig {
    let mut cfg = cfg.clone();
    cfg.adaptive.enabled = true;
    cfg.physics.smoothing.enabled = true;
    cfg
}

/// Device bytes of the same box with smoothing and adaptivity on (`cfg`, every stage's
/// buffers), per live particle and per particle of capacity (`adaptive.capacity_factor` slots
/// per particle).
fn adaptive_memory(
    ctx: &Arc<crate::gpu::Context>,
    cfg: &ShotConfig,
    b: &PbfBench,
) -> Result<serde_json::Value> {
    let sim = scene_sim(ctx, cfg, b)?;
    let bytes = sim.device_bytes() as f64;
    Ok(serde_json::json!({
        "fits": true,
        "capacity_factor": cfg.adaptive.capacity_factor,
        "device_bytes": bytes,
        "device_bytes_per_particle": bytes / sim.count() as f64,
        "device_bytes_per_capacity_slot": bytes / sim.capacity() as f64,
    }))
}
