//! `farm.json`: the plan of a farm. Every job with its script, command, dependencies and, once
//! submitted, its scheduler id; every wedge with its values and run directory. Written whole and
//! atomically, so `farm status` and the report job never read half a plan.
use super::wedge::Wedge;
use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub const PLAN: &str = "farm.json";
pub const REPORT: &str = "farm_report.json";
pub const SHEET: &str = "wedges_contact_sheet.png";

/// The kinds of job a farm runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobKind {
    /// One array task per wedge: run or resume the shot, requeued until it is complete.
    Simulation,
    /// One array task per (wedge, frame chunk), numbered `wedge * chunks + chunk`: waits until
    /// the run's manifest records the chunk's frames, then `nimbus export RUN --frames A-B`.
    Export,
    /// One array task per wedge: Blender renders the wedge's frames.
    Render,
    /// One task: checks every frame against the manifests, writes the report and contact sheet.
    Report,
}

/// A dependency on another job of the plan, in Slurm's words (`afterok`, `afterany`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dependency {
    pub job: String,
    pub kind: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Job {
    /// Unique in the plan: `sim`, `export`, `render`, `report`, and `sim.2`, `report.2` for
    /// resubmissions.
    pub name: String,
    pub kind: JobKind,
    /// The batch script, relative to the farm directory.
    pub script: String,
    /// The wedge indices of its array tasks (empty for a single job).
    pub tasks: Vec<usize>,
    /// What each task runs, readable (the script holds the exact shell).
    pub command: String,
    pub depends_on: Vec<Dependency>,
    /// The scheduler's job id once submitted (the array's id for a job array).
    pub slurm_id: Option<String>,
    /// The sbatch command line that submits it.
    pub submit: Vec<String>,
}

/// Slurm settings of the farm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SlurmSettings {
    pub partition: Option<String>,
    /// `--time` of every job (Slurm's formats: minutes, `MM:SS`, `HH:MM:SS`, `D-HH`, ...).
    pub time_limit: Option<String>,
    /// Seconds before the time limit at which the simulation gets SIGTERM (`--signal=B:TERM@`).
    pub signal_margin_s: u32,
    /// Requeues of one simulation task after a crash (killed by a signal other than the
    /// time-limit TERM); interruptions at the time limit requeue without limit.
    pub crash_requeues: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FarmPlan {
    pub tool: String,
    pub version: String,
    pub backend: String,
    pub shot: String,
    /// The config as given, and the copy in the farm directory that the jobs read.
    pub source_config: PathBuf,
    pub config: PathBuf,
    /// The nimbus binary the jobs run.
    pub nimbus: PathBuf,
    pub frame_start: u32,
    pub frame_end: u32,
    /// Frames each simulation task simulates before `frame_start` and does not write
    /// (`output.preroll`); a task stopped at the time limit in its pre-roll checkpoints there too.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub preroll_frames: u32,
    pub slurm: SlurmSettings,
    pub wedges: Vec<Wedge>,
    /// Render stage: Blender script and its output (`render/<shot>.<frame>.png` per run).
    pub render: Option<RenderSettings>,
    /// Export stage: `nimbus export` over frame chunks of every wedge.
    #[serde(default)]
    pub export: Option<ExportSettings>,
    pub jobs: Vec<Job>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportSettings {
    /// Frames per export task.
    pub chunk: u32,
    /// `export.key=value` overrides (`nimbus export --set`); never the run's own settings.
    pub sets: Vec<String>,
    /// `nimbus export --name` (default: a hash of the settings).
    pub name: Option<String>,
}

impl ExportSettings {
    /// Chunks of `start..=end`.
    pub fn chunks(&self, start: u32, end: u32) -> u32 {
        (end - start + 1).div_ceil(self.chunk)
    }

    /// The frames of chunk `c`.
    pub fn frames(&self, start: u32, end: u32, c: u32) -> (u32, u32) {
        let a = start + c * self.chunk;
        (a, (a + self.chunk - 1).min(end))
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    pub blender: PathBuf,
    pub script: PathBuf,
    /// Digits of the frame number in `render/<shot>.<frame>.png` (the shot's frame_padding).
    pub frame_padding: u32,
}

impl FarmPlan {
    pub fn load(farm_dir: &Path) -> Result<Self> {
        let path = farm_dir.join(PLAN);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            Error::InvalidInput(format!(
                "{}: {e} (not a farm directory written by `nimbus farm submit`)",
                path.display()
            ))
        })?;
        serde_json::from_str(&text).map_err(|e| {
            Error::InvalidInput(format!("{}: not a nimbus farm plan: {e}", path.display()))
        })
    }

    pub fn save(&self, farm_dir: &Path) -> Result<()> {
        let mut text =
            serde_json::to_string_pretty(self).map_err(|e| Error::Runtime(e.to_string()))?;
        text.push('\n');
        write_atomic(&farm_dir.join(PLAN), text.as_bytes())
    }

    pub fn job(&self, name: &str) -> Option<&Job> {
        self.jobs.iter().find(|j| j.name == name)
    }

    /// The newest job of a kind that runs wedge `index` (a resubmission replaces the first).
    pub fn latest_job_for(&self, kind: JobKind, index: usize) -> Option<&Job> {
        self.jobs
            .iter()
            .rev()
            .find(|j| j.kind == kind && j.tasks.contains(&index))
    }
}

/// `<farm>/runs/<wedge name>`: where a wedge's run directory lives.
fn is_zero(n: &u32) -> bool {
    *n == 0
}

pub fn run_dir(farm_dir: &Path, wedge: &Wedge) -> PathBuf {
    if wedge.run_dir.is_empty() {
        farm_dir.join("runs").join(&wedge.name)
    } else {
        farm_dir.join(&wedge.run_dir)
    }
}

#[cfg(test)]
mod tests {
    use super::ExportSettings;

    #[test]
    fn export_chunks_cover_the_range() {
        let e = ExportSettings {
            chunk: 8,
            sets: vec!["export.voxel_size=50".into()],
            name: None,
        };
        assert_eq!(e.chunks(1, 24), 3);
        assert_eq!(e.frames(1, 24, 2), (17, 24));
        assert_eq!(e.chunks(5, 21), 3);
        assert_eq!(e.frames(5, 21, 2), (21, 21));
        assert_eq!(e.chunks(3, 3), 1);
        assert_eq!(e.frames(3, 3, 0), (3, 3));
    }
}
