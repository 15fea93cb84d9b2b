//! `nimbus bench table1`: the paper's Table 1 (section 6) for its two scenarios, adaptive and not.
//!
//! Each scenario is the shot in `pipelines/paper_example{1,2}.yaml` (embedded, so the command runs
//! from any directory), with x and z of the domain scaled by `scale` (the height is kept so the
//! clouds still form at the same altitude). The non-adaptive counterpart is the same shot with
//! `adaptive.enabled=false` and the spacing of the finest adaptive level,
//! spacing * 2^(-max_level/3), so its particles are the size of the adaptive cloud particles,
//! as the paper sets its examples up. Both runs simulate the same physical time: `warmup` frames
//! (extended, for both, until the adaptive run has split particles), then `frames` measured ones.
//! Only the simulation runs: no splatting, no files.
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::sim::Simulation;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::sync::Arc;

/// (name in the table, config path, config text)
pub(super) const SCENARIOS: [(&str, &str, &str); 2] = [
    (
        "example 1 (Fig. 5a/b)",
        "pipelines/paper_example1.yaml",
        include_str!("../../pipelines/paper_example1.yaml"),
    ),
    (
        "example 2 (Fig. 5c/d)",
        "pipelines/paper_example2.yaml",
        include_str!("../../pipelines/paper_example2.yaml"),
    ),
];

/// Table columns: (column, phase_ms keys summed into it).
const COLUMNS: [(&str, &[&str]); 5] = [
    ("pbf", &["grid", "pbf", "velocity"]),
    ("smoothing", &["smoothing"]),
    ("cloud", &["cloud"]),
    ("split", &["split"]),
    ("merge", &["merge"]),
];

/// Warm-up frames are extended by at most this many times `warmup` (at least this many frames)
/// while waiting for the first split.
const WARMUP_EXTENSION: u32 = 4;

/// The scenario's adaptive config with x and z scaled (to whole multiples of the spacing, never
/// below 3 kernel radii, the periodic minimum); the non-adaptive one derives from it.
pub(super) fn scaled_config(origin: &str, text: &str, scale: f64) -> Result<ShotConfig> {
    let full = crate::shot::load_str(text, origin, &[])?.into_config();
    let d = &full.domain;
    let h0 = d.kernel_radius();
    let side = |s: f64| {
        let cells = (s * scale / d.spacing)
            .round()
            .max((3.0 * h0 / d.spacing).ceil());
        cells * d.spacing
    };
    let size = format!(
        "domain.size=[{},{},{}]",
        side(d.size[0]),
        d.size[1],
        side(d.size[2])
    );
    // The heating keeps its pattern (what makes the scene the scene): the heat sources move
    // and shrink with the width, and the noise keeps at least 2 cells per periodic axis (at a
    // quarter width, a 600 m noise over 832 m was one cell: uniform heating that only varied in
    // time, and differed from seed to seed).
    let (sx, sz) = (side(d.size[0]), side(d.size[2]));
    let mut overrides = vec![size, "adaptive.enabled=true".into()];
    let noise = full.physics.heat_noise_scale.min(0.5 * sx.min(sz));
    overrides.push(format!("physics.heat_noise_scale={noise}"));
    let f = sx / d.size[0];
    for (i, src) in full.physics.sources.iter().enumerate() {
        overrides.push(format!(
            "physics.sources[{i}].center=[{},{}]",
            src.center[0] * sx / d.size[0],
            src.center[1] * sz / d.size[2]
        ));
        if let Some(r) = src.radius {
            overrides.push(format!("physics.sources[{i}].radius={}", r * f));
        }
    }
    // The voxel size only matters for validation (the bench exports nothing); the spacing is a
    // multiple of it in the shots, so every scaled extent stays a whole number of voxels.
    Ok(crate::shot::load_str(text, origin, &overrides)?.into_config())
}

fn non_adaptive(cfg: &ShotConfig) -> Result<ShotConfig> {
    let mut c = cfg.clone();
    c.adaptive.enabled = false;
    c.domain.spacing = cfg.domain.spacing * 2f64.powf(-(cfg.adaptive.max_level as f64) / 3.0);
    crate::config::validate(&c)?;
    Ok(c)
}

/// Per-run accumulation over the measured frames.
#[derive(Default)]
pub(super) struct Run {
    max_particles: f64,
    phase_ms: BTreeMap<String, f64>,
    substeps: u64,
    wall_ms: f64,
    splits: f64,
    merges: f64,
    skipped_splits: f64,
    last: crate::sim::StepDiagnostics,
    /// Device bytes of the simulation (every stage's buffers).
    pub device_bytes: u64,
}

impl Run {
    fn column_ms(&self, keys: &[&str]) -> f64 {
        let sum: f64 = keys.iter().filter_map(|k| self.phase_ms.get(*k)).sum();
        sum / self.substeps.max(1) as f64
    }

    pub(super) fn total_ms(&self) -> f64 {
        COLUMNS.iter().map(|(_, k)| self.column_ms(k)).sum()
    }

    pub(super) fn to_json(&self, cfg: &ShotConfig, warmup_frames: u32, frames: u32) -> Value {
        let mut ms: serde_json::Map<String, Value> = COLUMNS
            .iter()
            .map(|(c, k)| (c.to_string(), json!(self.column_ms(k))))
            .collect();
        ms.insert("total".into(), json!(self.total_ms()));
        ms.insert(
            "wall".into(),
            json!(self.wall_ms / self.substeps.max(1) as f64),
        );
        let last = self.last.to_map();
        let levels: BTreeMap<&String, &f64> = last
            .iter()
            .filter(|(k, _)| k.starts_with("particles_level_"))
            .collect();
        json!({
            "adaptive": cfg.adaptive.enabled,
            "spacing": cfg.domain.spacing,
            "domain_size": cfg.domain.size,
            "max_particles": self.max_particles,
            "device_bytes": self.device_bytes,
            "final_particles": last.get("particles"),
            "final_particles_per_level": levels,
            "warmup_frames": warmup_frames,
            "measured_frames": frames,
            "measured_substeps": self.substeps,
            "ms_per_substep": ms,
            "phase_ms_per_substep": self.phase_ms.iter()
                .map(|(k, v)| (k.clone(), *v / self.substeps.max(1) as f64))
                .collect::<BTreeMap<_, _>>(),
            "splits": self.splits,
            "merges": self.merges,
            "skipped_splits": self.skipped_splits,
        })
    }
}

/// Runs `warmup` then `frames` frames; `extend` keeps warming up (up to a limit) until split
/// particles exist; past `warmup_until` the warm-up stops whatever it has reached (a bench
/// with a time limit). Returns the run and the warm-up frame count actually used.
pub(super) fn run(
    ctx: &Arc<Context>,
    cfg: &ShotConfig,
    (warmup, frames): (u32, u32),
    extend: bool,
    warmup_until: Option<std::time::Instant>,
    label: &str,
) -> Result<(Run, u32)> {
    let mut sim = Simulation::new(ctx.clone(), &crate::shot::Shot::prepare(cfg.clone())?)?;
    if !ctx.timestamps {
        sim.set_timing(crate::sim::Timing::HostWaits);
    }
    let mut r = Run {
        max_particles: sim.count() as f64,
        device_bytes: sim.device_bytes(),
        ..Run::default()
    };
    let limit = if extend {
        warmup.max(1) * (WARMUP_EXTENSION + 1)
    } else {
        warmup
    };
    let mut done = 0;
    while done < limit {
        let rep = sim.step_frame()?;
        done += 1;
        r.max_particles = r.max_particles.max(sim.count() as f64);
        let split = rep.diagnostics.refined() as f64;
        log::info!(
            "{label}: warm-up frame {done}: {} particles, {split} refined",
            sim.count()
        );
        if done >= warmup && (!extend || split > 0.0) {
            break;
        }
        if warmup_until.is_some_and(|t| std::time::Instant::now() > t) {
            log::warn!("{label}: warm-up stopped at its time limit after {done} frames");
            break;
        }
    }
    for f in 0..frames {
        let t0 = std::time::Instant::now();
        let rep = sim.step_frame()?;
        r.wall_ms += t0.elapsed().as_secs_f64() * 1e3;
        // the CFL control may take more than output.substeps
        r.substeps += rep.diagnostics.substeps.max(1) as u64;
        for (k, v) in rep.phases.by_key() {
            *r.phase_ms.entry(k).or_insert(0.0) += v;
        }
        let d = &rep.diagnostics;
        let sm = d.split_merge.unwrap_or_default();
        r.splits += sm.splits as f64;
        r.merges += sm.merges as f64;
        r.skipped_splits += sm.skipped_splits as f64;
        r.max_particles = r.max_particles.max(d.particles as f64);
        log::info!(
            "{label}: frame {}: {} particles, {} ms",
            f + 1,
            sim.count(),
            t0.elapsed().as_millis()
        );
        r.last = rep.diagnostics;
    }
    Ok((r, done))
}

/// The Table 1 benchmark; returns the figures as JSON, with the markdown table under "table".
pub fn bench_table1(scale: f64, frames: u32, warmup: u32) -> Result<Value> {
    if !(scale.is_finite() && scale > 0.0 && scale <= 1.0) {
        return Err(Error::InvalidInput(format!(
            "--scale must be in (0, 1], got {scale}"
        )));
    }
    if frames == 0 {
        return Err(Error::InvalidInput("--frames must be at least 1".into()));
    }
    let mut ctx = None;
    let mut scenarios = Vec::new();
    let mut rows = Vec::new();
    let mut summary = Vec::new();
    for (name, origin, text) in SCENARIOS {
        let ada = scaled_config(origin, text, scale)?;
        let non = non_adaptive(&ada)?;
        let ctx = match &ctx {
            Some(c) => Arc::clone(c),
            None => ctx.insert(Arc::new(Context::new(&ada.gpu)?)).clone(),
        };
        let (ra, used) = run(
            &ctx,
            &ada,
            (warmup, frames),
            true,
            None,
            &format!("{name} adaptive"),
        )?;
        // Same physical time for the non-adaptive run.
        let (rn, _) = run(
            &ctx,
            &non,
            (used, frames),
            false,
            None,
            &format!("{name} non-adaptive"),
        )?;
        let speedup = rn.total_ms() / ra.total_ms();
        let split_merge = (ra.column_ms(&["split"]) + ra.column_ms(&["merge"])) / ra.total_ms();
        let refined_now = ra.last.refined() as f64;
        for (r, adaptive) in [(&rn, false), (&ra, true)] {
            let cols: Vec<String> = COLUMNS
                .iter()
                .map(|(c, k)| {
                    if !adaptive && (*c == "split" || *c == "merge") {
                        "-".into()
                    } else {
                        format!("{:.2}", r.column_ms(k))
                    }
                })
                .collect();
            rows.push(format!(
                "| {name} | {} | {:.0} | {} | {:.2} |",
                if adaptive { "adaptive" } else { "non-adaptive" },
                r.max_particles,
                cols.join(" | "),
                r.total_ms()
            ));
        }
        scenarios.push(json!({
            "name": name,
            "config": origin,
            "non_adaptive": rn.to_json(&non, used, frames),
            "adaptive": ra.to_json(&ada, used, frames),
            "speedup": speedup,
            "split_merge_share": split_merge,
            "clouds_formed": refined_now > 0.0,
        }));
        summary.push(format!(
            "- {name}: adaptive is {speedup:.2}x faster per step; split + merge take {:.1}% of \
             its step{}",
            split_merge * 100.0,
            if refined_now > 0.0 {
                ""
            } else {
                " (no particle split: no cloud yet)"
            }
        ));
    }
    let adapter = ctx.as_ref().map(|c| (c.adapter_name(), c.timestamps));
    let table = format!(
        "| scenario | run | max particles | PBF ms | smoothing ms | cloud ms | split ms | merge ms | total ms |\n\
         |---|---|---|---|---|---|---|---|---|\n{}\n\n{}\n",
        rows.join("\n"),
        summary.join("\n")
    );
    Ok(json!({
        "scale": scale,
        "frames": frames,
        "warmup": warmup,
        "adapter": adapter.as_ref().map(|a| &a.0),
        "gpu_timestamps": adapter.map(|a| a.1),
        "note": "ms are averages per substep (the paper's step); PBF = grid + pbf + velocity",
        "scenarios": scenarios,
        "table": table,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_and_non_adaptive_configs() {
        let (_, origin, text) = SCENARIOS[0];
        let a = scaled_config(origin, text, 0.25).unwrap();
        assert!(a.adaptive.enabled);
        // 3200 * 0.25 = 800 m -> 12.5 spacings, rounded to 13 (832 m); height kept.
        assert_eq!(a.domain.size, [832.0, 1600.0, 832.0]);
        // ... and the heating noise keeps 2 cells per axis
        assert_eq!(a.physics.heat_noise_scale, 416.0);
        let (cell, period) = crate::ground::noise::lattice_for_extent(832.0, 416.0);
        assert_eq!((cell, period), (416.0, 2));
        // example 2's patches move and shrink with the width
        let (_, origin2, text2) = SCENARIOS[1];
        let b = scaled_config(origin2, text2, 0.25).unwrap();
        assert_eq!(b.physics.sources[0].center, [208.0, 208.0]);
        assert_eq!(b.physics.sources[0].radius, Some(104.0));
        let n = non_adaptive(&a).unwrap();
        assert!(!n.adaptive.enabled);
        // Level-3 particles: h = h0 2^-1, so the spacing halves.
        assert!((n.domain.spacing - 32.0).abs() < 1e-9);
        assert_eq!(n.domain.size, a.domain.size);
        // Tiny scales stop at 3 kernel radii (h0 = 128 m) along the periodic axes.
        let t = scaled_config(origin, text, 0.01).unwrap();
        assert_eq!(t.domain.size[0], 384.0);
        assert!(bench_table1(0.0, 1, 1).is_err());
        assert!(bench_table1(0.5, 0, 1).is_err());
    }
}
