//! What one frame of the simulation measured, typed: the phases' times and the step's own
//! diagnostics. stats.jsonl holds them (with `sim::diagnostics`' cloud and atmosphere figures)
//! under the names [`StepDiagnostics::insert_into`] writes, each written there alone.
use crate::sim::phase::PhaseTimes;
use std::collections::BTreeMap;

/// What one `step_frame` measured.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameReport {
    pub phases: PhaseTimes,
    pub diagnostics: StepDiagnostics,
}

/// The frame's split and merge counts (with adaptivity).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SplitMerge {
    pub splits: u32,
    pub merges: u32,
    /// Splits marked but left out (the children would not fit).
    pub skipped_splits: u32,
}

/// Particles per level at the frame's end, and their mass in units of m0 2^-max_level (exact).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Levels {
    /// Entry l: particles on level l, 0..=max_level.
    pub per_level: Vec<u64>,
    pub mass_units: u64,
}

/// The step's diagnostics of a frame (docs/PHYSICS.md "Diagnostics").
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepDiagnostics {
    /// Substeps the CFL control took.
    pub substeps: u32,
    /// Largest displacement per substep, in kernel radii, at the frame's end speeds.
    pub cfl_max: f64,
    /// |rho / rho0 - 1| of the last solve: mean and max.
    pub density_error_mean: f64,
    pub density_error_max: f64,
    /// max(rho / rho0 - 1, 0) of the last solve: mean and max.
    pub density_compression_mean: f64,
    pub density_compression_max: f64,
    /// Live particles at the frame's end.
    pub particles: u32,
    /// Times the host waited for the GPU in the frame.
    pub host_waits: u64,
    /// With adaptivity.
    pub split_merge: Option<SplitMerge>,
    /// With adaptivity.
    pub levels: Option<Levels>,
    /// With `control.target`: the cloud's overlap with the target.
    pub target_iou: Option<f64>,
    /// The figures of the forces of their own (`sim::stage::Stage::frame_figures`), by
    /// stats.jsonl name.
    pub forces: Vec<(&'static str, f64)>,
}

impl StepDiagnostics {
    /// Particles above level 0.
    pub fn refined(&self) -> u64 {
        self.levels
            .as_ref()
            .map_or(0, |l| l.per_level.iter().skip(1).sum())
    }

    /// Adds the figures under their stats.jsonl names.
    pub fn insert_into(&self, out: &mut BTreeMap<String, f64>) {
        let mut put = |k: &str, v: f64| {
            out.insert(k.to_string(), v);
        };
        put("substeps", self.substeps as f64);
        put("cfl_max", self.cfl_max);
        put("density_error_mean", self.density_error_mean);
        put("density_error_max", self.density_error_max);
        put("density_compression_mean", self.density_compression_mean);
        put("density_compression_max", self.density_compression_max);
        put("particles", self.particles as f64);
        put("host_waits", self.host_waits as f64);
        if let Some(s) = self.split_merge {
            put("splits", s.splits as f64);
            put("merges", s.merges as f64);
            put("skipped_splits", s.skipped_splits as f64);
        }
        if let Some(l) = &self.levels {
            for (level, n) in l.per_level.iter().enumerate() {
                put(&format!("particles_level_{level}"), *n as f64);
            }
            put("mass_units", l.mass_units as f64);
        }
        if let Some(iou) = self.target_iou {
            put("target_iou", iou);
        }
        for (name, v) in &self.forces {
            put(name, *v);
        }
    }

    /// The figures under their stats.jsonl names.
    pub fn to_map(&self) -> BTreeMap<String, f64> {
        let mut out = BTreeMap::new();
        self.insert_into(&mut out);
        out
    }
}
