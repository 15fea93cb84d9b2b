//! `nimbus farm status`: the state of every job and wedge, from the queue (`squeue`), the
//! attempts each simulation task logs in `state/` and the run directories' manifests. The files
//! keep the answer after Slurm has forgotten a finished job.
use super::openjd;
use super::plan::{run_dir, FarmPlan, JobKind, REPORT};
use super::slurm::{self, QueueEntry};
use crate::pipeline::records::Manifest;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// One attempt of a simulation task, as its script logs it.
#[derive(Debug, Clone, serde::Deserialize, Serialize)]
pub struct Attempt {
    pub job: String,
    pub restart: u32,
    pub exit: i32,
    pub at: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct WedgeStatus {
    pub index: usize,
    pub name: String,
    pub values: String,
    pub run_dir: String,
    /// pending, running, requeued, done, failed, not submitted, unknown.
    pub state: String,
    pub frames_done: usize,
    pub frames_total: u32,
    /// The array task of the newest simulation job for the wedge (`<array id>_<index>`).
    pub job: Option<String>,
    pub restarts: u32,
    pub attempts: usize,
    pub last_exit: Option<i32>,
    /// The queue's reason (pending) or what went wrong (failed).
    pub note: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct JobStatus {
    pub name: String,
    pub kind: JobKind,
    pub slurm_id: Option<String>,
    /// For an array: its tasks' states counted (`2 running, 1 pending`); else the state.
    pub state: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct FarmStatus {
    pub farm_dir: String,
    pub shot: String,
    pub frame_start: u32,
    pub frame_end: u32,
    /// Frames simulated before `frame_start` (`output.preroll`): a task in its pre-roll has
    /// written no frame yet.
    pub preroll_frames: u32,
    pub jobs: Vec<JobStatus>,
    pub wedges: Vec<WedgeStatus>,
    /// True once every wedge is done and the report says complete.
    pub complete: bool,
    pub report: Option<String>,
    /// Printed for wedges that failed: resumes them from their checkpoints.
    pub resubmit_command: Option<String>,
    /// Why the queue could not be read (states then come from the files alone).
    pub scheduler_error: Option<String>,
}

pub fn attempts(farm_dir: &Path, index: usize) -> Vec<Attempt> {
    let path = farm_dir.join("state").join(format!("sim_{index}.jsonl"));
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// The farm's state now. Never fails: what cannot be read is named in the answer.
pub fn collect(plan: &FarmPlan, farm_dir: &Path) -> FarmStatus {
    let ids: Vec<&str> = plan
        .jobs
        .iter()
        .filter_map(|j| j.slurm_id.as_deref())
        .collect();
    // An OpenJD farm has no queue nimbus can ask (the farm manager's own tools show its
    // tasks): its state comes from the farm's files alone.
    let openjd = plan.backend == "openjd";
    let (queue, scheduler_error) = if openjd {
        (BTreeMap::new(), None)
    } else {
        match slurm::queue(&ids) {
            Ok(q) => (q, None),
            Err(e) => (BTreeMap::new(), Some(e.to_string())),
        }
    };
    let frames_total = plan.frame_end - plan.frame_start + 1;
    let mut wedges = Vec::new();
    for w in &plan.wedges {
        let dir = run_dir(farm_dir, w);
        let manifest = Manifest::load(&crate::pipeline::run_dir::RunDir::new(&dir)).ok();
        let frames_done = manifest.as_ref().map_or(0, |m| m.frames.len());
        let complete = manifest.as_ref().is_some_and(|m| m.complete);
        let job = plan.latest_job_for(JobKind::Simulation, w.index);
        let task = job.and_then(|j| j.slurm_id.as_ref().map(|id| format!("{id}_{}", w.index)));
        let tries = attempts(farm_dir, w.index);
        let last_exit = tries.last().map(|a| a.exit);
        let entry = task.as_ref().and_then(|t| queue.get(t));
        // Attempts of this job's task (not of an earlier round's): a pending task with one is
        // a requeued one.
        let own = task
            .as_ref()
            .is_some_and(|t| tries.iter().any(|a| &a.job == t));
        let (state, note) = if openjd {
            openjd_wedge_state(complete, &tries, frames_done)
        } else {
            wedge_state(
                complete,
                job.is_some_and(|j| j.slurm_id.is_some()),
                entry,
                &tries,
                own,
                scheduler_error.is_some(),
            )
        };
        wedges.push(WedgeStatus {
            index: w.index,
            name: w.name.clone(),
            values: w.label(),
            run_dir: dir.display().to_string(),
            state,
            frames_done,
            frames_total,
            job: task,
            restarts: entry
                .map(|e| e.restarts)
                .unwrap_or_else(|| tries.iter().map(|a| a.restart).max().unwrap_or(0)),
            attempts: tries.len(),
            last_exit,
            note,
        });
    }
    let jobs = plan
        .jobs
        .iter()
        .map(|j| JobStatus {
            name: j.name.clone(),
            kind: j.kind,
            slurm_id: j.slurm_id.clone(),
            state: if openjd {
                openjd_job_state(j.kind, farm_dir)
            } else {
                job_state(j.slurm_id.as_deref(), &j.tasks, j.kind, &queue, farm_dir)
            },
        })
        .collect();
    let report_path = farm_dir.join(REPORT);
    let report_complete = std::fs::read_to_string(&report_path)
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|v| v["complete"] == true);
    let failed = wedges
        .iter()
        .any(|w| w.state == "failed" || w.state == "interrupted");
    FarmStatus {
        farm_dir: farm_dir.display().to_string(),
        shot: plan.shot.clone(),
        frame_start: plan.frame_start,
        frame_end: plan.frame_end,
        preroll_frames: plan.preroll_frames,
        jobs,
        complete: report_complete && wedges.iter().all(|w| w.state == "done"),
        wedges,
        report: report_path
            .exists()
            .then(|| report_path.display().to_string()),
        resubmit_command: failed.then(|| {
            if openjd {
                // Run again, the wedges resume from their checkpoints (in a farm manager: retry
                // the failed tasks).
                format!(
                    "openjd run {} --step Report --run-dependencies",
                    slurm::sh(&farm_dir.join(openjd::TEMPLATE).to_string_lossy())
                )
            } else {
                format!(
                    "nimbus farm resubmit {}",
                    slurm::sh(&farm_dir.to_string_lossy())
                )
            }
        }),
        scheduler_error,
    }
}

/// A wedge of an OpenJD farm, from its run and the attempts its Simulation tasks logged: done,
/// interrupted (stopped at a checkpoint: a retry resumes it), failed, not run, or incomplete
/// (running now, or stopped without a record).
fn openjd_wedge_state(complete: bool, tries: &[Attempt], frames_done: usize) -> (String, String) {
    if complete {
        return ("done".into(), String::new());
    }
    match tries.last() {
        Some(a) if a.exit == 130 => (
            "interrupted".into(),
            "stopped at a checkpoint (exit 130); a retry of its task resumes it".into(),
        ),
        Some(a) if a.exit != 0 => (
            "failed".into(),
            if a.exit > 128 {
                format!("killed by signal {} (exit {})", a.exit - 128, a.exit)
            } else {
                format!("exit {} (see the task's log)", a.exit)
            },
        ),
        _ if frames_done == 0 => ("not run".into(), String::new()),
        _ => (
            "incomplete".into(),
            "running, or stopped without a record".into(),
        ),
    }
}

/// A step of an OpenJD farm: only the report leaves a trace nimbus can read.
fn openjd_job_state(kind: JobKind, farm_dir: &Path) -> String {
    let step = openjd::step_name(kind);
    if kind == JobKind::Report && farm_dir.join(REPORT).exists() {
        return format!("step {step}: completed");
    }
    format!("step {step}")
}

/// A wedge's state from its run, its queue entry and its logged attempts.
fn wedge_state(
    complete: bool,
    submitted: bool,
    entry: Option<&QueueEntry>,
    tries: &[Attempt],
    own_attempt: bool,
    queue_unknown: bool,
) -> (String, String) {
    if complete {
        return ("done".into(), String::new());
    }
    if !submitted {
        return ("not submitted".into(), "a --dry-run plan".into());
    }
    let interrupted = tries.last().is_some_and(|a| a.exit == 130);
    if let Some(e) = entry {
        match e.state.as_str() {
            "PENDING" if e.restarts > 0 || own_attempt => {
                return ("requeued".into(), e.reason.clone())
            }
            "PENDING" => return ("pending".into(), e.reason.clone()),
            "REQUEUED" | "REQUEUE_FED" | "REQUEUE_HOLD" => {
                return ("requeued".into(), e.reason.clone())
            }
            "RUNNING" | "CONFIGURING" | "COMPLETING" | "SUSPENDED" | "RESIZING" => {
                return ("running".into(), String::new())
            }
            // A finished entry: the attempts below say how.
            _ => {}
        }
    }
    if queue_unknown {
        return ("unknown".into(), "the queue could not be read".into());
    }
    let note = match (tries.last(), entry) {
        (Some(a), _) if a.exit == 0 => "exited 0 but its run is not complete".to_string(),
        (Some(_), Some(e)) if interrupted && e.state == "CANCELLED" => {
            "cancelled (scancel), not requeued".to_string()
        }
        (Some(_), _) if interrupted => "interrupted (exit 130) and not requeued".to_string(),
        (Some(a), _) if a.exit > 128 => format!(
            "killed by signal {} (exit {}) after {} attempt(s)",
            a.exit - 128,
            a.exit,
            tries.len()
        ),
        (Some(a), _) => format!("exit {} (see logs/sim_<index>.log)", a.exit),
        (None, Some(e)) => format!("{} before it ran", e.state.to_lowercase()),
        (None, None) => "left the queue without running".to_string(),
    };
    ("failed".into(), note)
}

/// An array's tasks counted by state, or a single job's state (done when it left the queue).
fn job_state(
    id: Option<&str>,
    tasks: &[usize],
    kind: JobKind,
    queue: &BTreeMap<String, QueueEntry>,
    farm_dir: &Path,
) -> String {
    let Some(id) = id else {
        return "not submitted".into();
    };
    let entries: Vec<&QueueEntry> = queue
        .iter()
        .filter(|(k, _)| {
            *k == id || k.starts_with(&format!("{id}_")) || k.starts_with(&format!("{id}_["))
        })
        .map(|(_, e)| e)
        .collect();
    if entries.is_empty() {
        if kind == JobKind::Report && farm_dir.join(REPORT).exists() {
            return "completed".into();
        }
        return if tasks.is_empty() {
            "left the queue".into()
        } else {
            format!("{} tasks left the queue", tasks.len())
        };
    }
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for e in entries {
        *counts.entry(e.state.to_lowercase()).or_default() += 1;
    }
    counts
        .iter()
        .map(|(s, n)| format!("{n} {s}"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The human form: one line per job, one per wedge.
pub fn render_text(s: &FarmStatus) -> String {
    let mut out = format!(
        "farm {} (shot '{}', {} wedges, frames {}..={}{})\n",
        s.farm_dir,
        s.shot,
        s.wedges.len(),
        s.frame_start,
        s.frame_end,
        if s.preroll_frames > 0 {
            format!(", after a pre-roll of {} frames", s.preroll_frames)
        } else {
            String::new()
        }
    );
    if let Some(e) = &s.scheduler_error {
        out += &format!("warning: {e}\n");
    }
    out += "jobs:\n";
    for j in &s.jobs {
        out += &format!(
            "  {:<10} {:<8} {}\n",
            j.name,
            j.slurm_id.as_deref().unwrap_or("-"),
            j.state
        );
    }
    out += "wedges:\n";
    for w in &s.wedges {
        out += &format!(
            "  {:<40} {:<13} {:>4}/{:<4} job {:<10} restarts {}  {}{}\n",
            w.name,
            w.state,
            w.frames_done,
            w.frames_total,
            w.job.as_deref().unwrap_or("-"),
            w.restarts,
            w.values,
            if w.note.is_empty() {
                String::new()
            } else {
                format!("  ({})", w.note)
            }
        );
    }
    if let Some(r) = &s.report {
        out += &format!("report: {r}\n");
    }
    out += &format!("complete: {}\n", s.complete);
    if let Some(c) = &s.resubmit_command {
        out += &format!("resubmit the failed wedges (they resume from their checkpoints): {c}\n");
    }
    out
}
