//! `nimbus bench step`: the full adaptive step (PBF, temperature smoothing, cloud physics, split
//! and merge) at scale: paper example 1 (`pipelines/paper_example1.yaml`, as `bench table1`
//! runs it) widened in x and z to about `--particles` particles at level 0. Wider, not finer:
//! the spacing, time step and heating pattern stay the paper's, so every particle does the
//! same work as in the paper's scene and the figure is the cost of more of them. Warms up until
//! clouds have formed (split particles), then measures ms per substep per phase and particle
//! steps per second. The 1M and 10M figures on a GPU come from `tools/gpu_machine.sh`.
use super::table1;
use crate::error::{Error, Result};
use crate::gpu::Context;
use serde_json::{json, Value};
use std::sync::Arc;

/// The full step of paper example 1 widened to about `particles` particles; with
/// `max_seconds`, the warm-up stops at 80% of it (the figures then may be of clear air:
/// `clouds_formed` says).
pub fn bench_step(
    particles: usize,
    frames: u32,
    warmup: u32,
    max_seconds: Option<f64>,
) -> Result<Value> {
    let started = std::time::Instant::now();
    if particles == 0 || frames == 0 {
        return Err(Error::InvalidInput(
            "--particles and --frames must be at least 1".into(),
        ));
    }
    let (name, origin, text) = table1::SCENARIOS[0];
    let paper = table1::scaled_config(origin, text, 1.0)?;
    let n0 = crate::config::lattice_count(&paper.domain);
    // particles per column stay; columns grow with the square of the scale
    let scale = (particles as f64 / n0).sqrt();
    let cfg = table1::scaled_config(origin, text, scale)?;
    let n = crate::config::lattice_count(&cfg.domain) as u64;
    let ctx = Arc::new(Context::new(&cfg.gpu)?);
    // refused before anything is computed when the device cannot hold it
    crate::sim::footprint::check_shot(&ctx, &crate::shot::Shot::prepare(cfg.clone())?, n)?;
    let until = max_seconds.map(|t| started + std::time::Duration::from_secs_f64(0.8 * t.max(0.0)));
    let (r, used) = table1::run(&ctx, &cfg, (warmup, frames), true, until, name)?;
    let mut out = r.to_json(&cfg, used, frames);
    let total_ms = r.total_ms();
    let live = out["final_particles"].as_f64().unwrap_or(n as f64);
    let refined: f64 = out["final_particles_per_level"]
        .as_object()
        .map(|l| {
            l.iter()
                .filter(|(k, _)| k.as_str() != "particles_level_0")
                .filter_map(|(_, v)| v.as_f64())
                .sum()
        })
        .unwrap_or(0.0);
    let o = out.as_object_mut().expect("a JSON object");
    // without split particles the step measured has no cloud in it (too few warm-up frames)
    o.insert("clouds_formed".into(), json!(refined > 0.0));
    o.insert("scene".into(), json!(format!("{name}, widened")));
    o.insert("scale_xz".into(), json!(scale));
    o.insert("initial_particles".into(), json!(n));
    o.insert("adapter".into(), json!(ctx.adapter_name()));
    o.insert("adapter_info".into(), ctx.describe());
    o.insert("gpu_timestamps".into(), json!(ctx.timestamps));
    o.insert("step_ms".into(), json!(total_ms));
    // the substep is the paper's step; particles of the last measured frame
    o.insert(
        "particle_steps_per_second".into(),
        json!(live / (total_ms / 1e3)),
    );
    o.insert(
        "device_bytes_per_particle".into(),
        json!(r.device_bytes as f64 / n as f64),
    );
    o.insert(
        "note".into(),
        json!("ms are averages per substep (the paper's step): pbf = grid + pbf + velocity, then smoothing, cloud, split, merge; step_ms their sum"),
    );
    Ok(out)
}
