//! `nimbus bench pbf`: milliseconds per PBF substep and per phase, device bytes per particle.
use crate::config::{GpuConfig, ShotConfig};
use crate::error::{Error, Result};
use crate::sim::Simulation;
use std::sync::Arc;

/// A periodic box of about `particles` particles at spacing 1 m (cube, x/z periodic, walls in y),
/// gravity on, default solver settings, one substep per frame.
pub fn bench_config(particles: usize) -> Result<ShotConfig> {
    let side = (particles as f64).cbrt().round().max(4.0);
    let yaml = format!(
        "shot: bench\noutput: {{frames: {{start: 0, end: 1}}, substeps: 1, frame_seconds: 0.02}}\n\
         domain: {{size: [{side}, {side}, {side}], spacing: 1.0}}\nsolver: {{gravity: 9.81}}\n"
    );
    serde_saphyr::from_str(&yaml).map_err(|e| Error::Config(format!("bench config: {e}")))
}

/// Runs `steps` substeps after `warmup` (at least one: pipeline compilation, first grid build);
/// returns the figures as JSON.
pub fn bench_pbf(particles: usize, steps: u32, warmup: u32) -> Result<serde_json::Value> {
    let cfg = bench_config(particles)?;
    let ctx = Arc::new(crate::gpu::Context::new(&GpuConfig::default())?);
    let mut sim = Simulation::new(ctx.clone(), &cfg)?;
    if !ctx.timestamps {
        sim.set_timing(crate::sim::Timing::HostWaits);
    }
    for _ in 0..warmup.max(1) {
        sim.step_frame()?;
    }
    let mut phases = std::collections::BTreeMap::<String, f64>::new();
    let t0 = std::time::Instant::now();
    let mut last = None;
    for _ in 0..steps.max(1) {
        let r = sim.step_frame()?;
        for (k, v) in r.phases.by_key() {
            *phases.entry(k).or_insert(0.0) += v;
        }
        last = Some(r);
    }
    let wall = t0.elapsed().as_secs_f64() * 1e3 / steps.max(1) as f64;
    let n = sim.count();
    for v in phases.values_mut() {
        *v /= steps.max(1) as f64;
    }
    let diag = last.map(|r| r.diagnostics).unwrap_or_default();
    let adaptive = adaptive_memory(&ctx, &cfg)?;
    Ok(serde_json::json!({
        "particles": n,
        "boundary_particles": sim.boundary_count(),
        "steps": steps,
        "warmup": warmup.max(1),
        "iterations": cfg.solver.iterations,
        "adapter": ctx.adapter_name(),
        "gpu_timestamps": ctx.timestamps,
        "ms_per_substep_wall": wall,
        "phase_ms": phases,
        "device_bytes": sim.device_bytes(),
        "device_bytes_per_particle": sim.device_bytes() as f64 / n as f64,
        "with_adaptivity": adaptive,
        "diagnostics": diag,
    }))
}

/// Device bytes of the same box with smoothing and adaptivity on (every stage's buffers), per
/// live particle and per particle of capacity (`adaptive.capacity_factor` slots per particle).
fn adaptive_memory(ctx: &Arc<crate::gpu::Context>, cfg: &ShotConfig) -> Result<serde_json::Value> {
    let mut cfg = cfg.clone();
    cfg.adaptive.enabled = true;
    cfg.physics.smoothing.enabled = true;
    let sim = Simulation::new(ctx.clone(), &cfg)?;
    let bytes = sim.device_bytes() as f64;
    Ok(serde_json::json!({
        "capacity_factor": cfg.adaptive.capacity_factor,
        "device_bytes": bytes,
        "device_bytes_per_particle": bytes / sim.count() as f64,
        "device_bytes_per_capacity_slot": bytes / sim.capacity() as f64,
    }))
}
