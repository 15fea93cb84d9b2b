//! `nimbus farm submit` and `nimbus farm resubmit`: validate the wedges, write the farm
//! directory (plan, config copy, batch scripts), then hand the jobs to `sbatch` in dependency
//! order, recording each id in the plan as it is given.
use super::openjd;
use super::plan::{
    self, Dependency, ExportSettings, FarmPlan, Job, JobKind, RenderSettings, SlurmSettings,
};
use super::slurm;
use super::wedge::{self, WedgeAxis};
use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use std::path::{Path, PathBuf};

/// Seconds of warning before the time limit by default: a frame and a checkpoint of a
/// production shot take well under this.
pub const DEFAULT_SIGNAL_MARGIN_S: u32 = 120;

/// Where a farm runs: `--backend`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// Batch scripts handed to `sbatch`.
    Slurm,
    /// One Open Job Description template (AWS Deadline Cloud; `openjd run` here).
    #[value(name = "openjd")]
    OpenJd,
}

impl Backend {
    pub fn name(self) -> &'static str {
        match self {
            Backend::Slurm => "slurm",
            Backend::OpenJd => "openjd",
        }
    }
}

pub struct SubmitOptions {
    pub config: PathBuf,
    pub backend: Backend,
    /// `--run-local`: run the OpenJD template here with `openjd run` (openjd backend only).
    pub run_local: bool,
    pub wedges: Vec<String>,
    pub out: Option<PathBuf>,
    pub partition: Option<String>,
    pub time_limit: Option<String>,
    pub signal_margin_s: u32,
    pub crash_requeues: u32,
    pub render: bool,
    /// Export stage: frames per `nimbus export` task (`--export-chunk`).
    pub export_chunk: Option<u32>,
    /// `--export-set export.key=value` of the export tasks.
    pub export_sets: Vec<String>,
    /// `--export-name`: the export directory's name under each run's `exports/`.
    pub export_name: Option<String>,
    pub dry_run: bool,
}

/// What a submission did, for the command line to print.
pub struct Submitted {
    pub farm_dir: PathBuf,
    pub plan: FarmPlan,
    /// (job name, sbatch command line, id when submitted).
    pub jobs: Vec<(String, String, Option<String>)>,
    /// The OpenJD backend: the template written.
    pub template: Option<PathBuf>,
    /// The OpenJD backend with `--run-local`: what `openjd run` did.
    pub local_run: Option<super::openjd::LocalRun>,
}

pub fn submit(opts: &SubmitOptions) -> Result<Submitted> {
    // Everything that can be refused is refused before the farm directory is written.
    let cfg = crate::shot::load(&opts.config, &[])?.into_config();
    let axes = opts
        .wedges
        .iter()
        .map(|w| wedge::parse_axis(w))
        .collect::<Result<Vec<WedgeAxis>>>()?;
    let wedges = wedge::combinations(&cfg.shot, &axes)?;
    wedge::validate_all(&opts.config, &wedges)?;
    if let Some(t) = &opts.time_limit {
        check_time_limit(t, opts.signal_margin_s)?;
    }
    if let Some(p) = &opts.partition {
        if p.is_empty()
            || !p
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
        {
            return Err(Error::InvalidInput(format!(
                "--partition {p:?}: not a partition name"
            )));
        }
    }
    check_backend_flags(opts)?;
    let export = export_settings(opts, &wedges)?;
    let render = if opts.render {
        Some(render_settings(cfg.output.frame_padding)?)
    } else {
        None
    };

    let farm_dir = opts
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("{}_farm", cfg.shot)));
    if farm_dir.join(plan::PLAN).exists() {
        return Err(Error::InvalidInput(format!(
            "{}: already holds a farm; see `nimbus farm status {0}` or `nimbus farm resubmit {0}`",
            farm_dir.display()
        )));
    }
    for d in ["jobs", "logs", "state", "runs"] {
        let p = farm_dir.join(d);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
    }
    let farm_dir = farm_dir
        .canonicalize()
        .map_err(|e| Error::io(&farm_dir, e))?;
    // The jobs read a copy: editing the shot after submitting does not change a running farm.
    let config_copy = farm_dir.join("shot.yaml");
    let text = std::fs::read(&opts.config).map_err(|e| Error::io(&opts.config, e))?;
    write_atomic(&config_copy, &text)?;

    let nimbus = std::env::current_exe()
        .and_then(|p| p.canonicalize())
        .map_err(|e| Error::Runtime(format!("cannot find the nimbus binary: {e}")))?;
    let mut wedges = wedges;
    for w in &mut wedges {
        let mut words = vec![
            "nimbus".to_string(),
            "run".into(),
            config_copy.to_string_lossy().into_owned(),
            "--out".into(),
            plan::run_dir(&farm_dir, w).to_string_lossy().into_owned(),
        ];
        let mut sets = w.sets();
        // `nimbus export` splats the particle caches the simulation writes.
        if export.is_some() {
            sets.push("export.particles=true".into());
        }
        for kv in sets {
            words.push("--set".into());
            words.push(kv);
        }
        w.command = words
            .iter()
            .map(|a| slurm::sh(a))
            .collect::<Vec<_>>()
            .join(" ");
    }
    let all: Vec<usize> = wedges.iter().map(|w| w.index).collect();
    let mut plan = FarmPlan {
        tool: "nimbus".into(),
        version: crate::VERSION.into(),
        backend: opts.backend.name().into(),
        shot: cfg.shot.clone(),
        source_config: opts
            .config
            .canonicalize()
            .unwrap_or_else(|_| opts.config.clone()),
        config: config_copy,
        nimbus,
        frame_start: cfg.output.frames.start,
        frame_end: cfg.output.frames.end,
        preroll_frames: cfg.output.preroll_frames(),
        slurm: SlurmSettings {
            partition: opts.partition.clone(),
            time_limit: opts.time_limit.clone(),
            signal_margin_s: opts.signal_margin_s,
            crash_requeues: opts.crash_requeues,
        },
        wedges,
        render,
        export,
        jobs: Vec::new(),
    };
    add_jobs(&mut plan, &all, "");
    match opts.backend {
        Backend::Slurm => write_and_submit(plan, farm_dir, opts.dry_run, 0),
        Backend::OpenJd => write_openjd(plan, farm_dir, opts.run_local),
    }
}

/// The OpenJD backend: the plan's jobs as the steps of one template; with `--run-local`,
/// `openjd run` of the whole template here.
fn write_openjd(mut plan: FarmPlan, farm_dir: PathBuf, run_local: bool) -> Result<Submitted> {
    openjd::adapt_jobs(&mut plan, &farm_dir);
    let template = openjd::write(&plan, &farm_dir)?;
    plan.save(&farm_dir)?;
    let jobs = plan
        .jobs
        .iter()
        .map(|j| {
            (
                format!("step {}", openjd::step_name(j.kind)),
                j.command.clone(),
                None,
            )
        })
        .collect();
    let local_run = if run_local {
        Some(openjd::run_local(&farm_dir)?)
    } else {
        None
    };
    Ok(Submitted {
        farm_dir,
        plan,
        jobs,
        template: Some(template),
        local_run,
    })
}

/// Flags that belong to one backend are refused with the other (exit 2).
fn check_backend_flags(opts: &SubmitOptions) -> Result<()> {
    match opts.backend {
        Backend::Slurm => {
            if opts.run_local {
                return Err(Error::InvalidInput(
                    "--run-local runs an Open Job Description template: it needs --backend openjd"
                        .into(),
                ));
            }
        }
        Backend::OpenJd => {
            if opts.partition.is_some() {
                return Err(Error::InvalidInput(
                    "--partition is a Slurm setting; with --backend openjd the farm manager's \
                     queue and host requirements choose the workers"
                        .into(),
                ));
            }
            if opts.signal_margin_s == 0 || opts.signal_margin_s > openjd::MAX_NOTIFY_S {
                return Err(Error::InvalidInput(format!(
                    "--signal-margin {}: with --backend openjd it is the cancelation notice \
                     (notifyPeriodInSeconds), 1 to {} seconds",
                    opts.signal_margin_s,
                    openjd::MAX_NOTIFY_S
                )));
            }
            if opts.run_local && opts.dry_run {
                return Err(Error::InvalidInput(
                    "--run-local and --dry-run contradict each other (without --run-local, \
                     --backend openjd only writes the template)"
                        .into(),
                ));
            }
        }
    }
    Ok(())
}

/// Adds the simulation, render and report jobs for `tasks` (wedge indices); `suffix` tells a
/// resubmission's jobs from the first ones (`sim.2`).
fn add_jobs(plan: &mut FarmPlan, tasks: &[usize], suffix: &str) {
    let sim = format!("sim{suffix}");
    plan.jobs.push(Job {
        name: sim.clone(),
        kind: JobKind::Simulation,
        script: "jobs/sim.sbatch".into(),
        tasks: tasks.to_vec(),
        command: "per wedge: its `command` in wedges[], or `nimbus resume RUN` once the run has \
                  a checkpoint"
            .into(),
        depends_on: Vec::new(),
        slurm_id: None,
        submit: Vec::new(),
    });
    let mut report_deps = vec![Dependency {
        job: sim.clone(),
        kind: "afterany".into(),
    }];
    if let Some(e) = &plan.export {
        let export = format!("export{suffix}");
        let mut command = "per (wedge, chunk): once RUN/manifest.json records frames A-B, nimbus export RUN --frames A-B".to_string();
        for kv in &e.sets {
            command += &format!(" --set {}", slurm::sh(kv));
        }
        if let Some(n) = &e.name {
            command += &format!(" --name {}", slurm::sh(n));
        }
        plan.jobs.push(Job {
            name: export.clone(),
            kind: JobKind::Export,
            script: "jobs/export.sbatch".into(),
            tasks: tasks.to_vec(),
            command,
            // after: the chunks start once the simulation has, and each waits for its frames
            // in the manifest; they overlap the simulation instead of following it.
            depends_on: vec![Dependency {
                job: sim.clone(),
                kind: "after".into(),
            }],
            slurm_id: None,
            submit: Vec::new(),
        });
        report_deps.push(Dependency {
            job: export,
            kind: "afterany".into(),
        });
    }
    if plan.render.is_some() {
        let render = format!("render{suffix}");
        plan.jobs.push(Job {
            name: render.clone(),
            kind: JobKind::Render,
            script: "jobs/render.sbatch".into(),
            tasks: tasks.to_vec(),
            command: "blender -b --factory-startup --python-exit-code 1 -P tools/render_blender.py -- RUN RUN/render/<shot>.<frame>.png --frame FRAME".into(),
            // afterany: with afterok one failed wedge would leave every render task (and the
            // report after them) pending forever; a task whose frame is missing fails on its own.
            depends_on: vec![Dependency {
                job: sim,
                kind: "afterany".into(),
            }],
            slurm_id: None,
            submit: Vec::new(),
        });
        report_deps.push(Dependency {
            job: render,
            kind: "afterany".into(),
        });
    }
    plan.jobs.push(Job {
        name: format!("report{suffix}"),
        kind: JobKind::Report,
        script: "jobs/report.sbatch".into(),
        tasks: Vec::new(),
        command: "nimbus farm report FARM_DIR".into(),
        depends_on: report_deps,
        slurm_id: None,
        submit: Vec::new(),
    });
}

/// Writes the scripts and the plan, then submits the jobs not yet submitted (from `first`).
fn write_and_submit(
    mut plan: FarmPlan,
    farm_dir: PathBuf,
    dry_run: bool,
    first: usize,
) -> Result<Submitted> {
    for job in &plan.jobs[first..] {
        let text = slurm::script_for(&plan, job, &farm_dir);
        let path = farm_dir.join(&job.script);
        write_atomic(&path, text.as_bytes())?;
        make_executable(&path)?;
    }
    let frames = plan.frame_end - plan.frame_start + 1;
    let mut shown = Vec::new();
    for i in first..plan.jobs.len() {
        let args = slurm::submit_args(&plan.jobs[i], &plan, &farm_dir, frames);
        plan.jobs[i].submit = args.clone();
        plan.save(&farm_dir)?;
        let line = args
            .iter()
            .map(|a| slurm::sh(a))
            .collect::<Vec<_>>()
            .join(" ");
        let id = if dry_run {
            None
        } else {
            match slurm::sbatch(&args) {
                Ok(id) => Some(id),
                Err(e) => {
                    let done: Vec<String> = shown
                        .iter()
                        .filter_map(|(n, _, id): &(String, String, Option<String>)| {
                            id.as_ref().map(|id| format!("{n}={id}"))
                        })
                        .collect();
                    return Err(Error::Runtime(format!(
                        "{e} (job '{}' not submitted{}; the plan is in {}{})",
                        plan.jobs[i].name,
                        if done.is_empty() {
                            String::new()
                        } else {
                            format!(", already submitted: {}", done.join(" "))
                        },
                        farm_dir.join(plan::PLAN).display(),
                        if done.is_empty() {
                            format!(
                                "; submit it later with: nimbus farm resubmit {}",
                                slurm::sh(&farm_dir.to_string_lossy())
                            )
                        } else {
                            String::new()
                        }
                    )));
                }
            }
        };
        plan.jobs[i].slurm_id = id.clone();
        plan.save(&farm_dir)?;
        shown.push((plan.jobs[i].name.clone(), line, id));
    }
    Ok(Submitted {
        farm_dir,
        plan,
        jobs: shown,
        template: None,
        local_run: None,
    })
}

/// `nimbus farm resubmit`: a new simulation array over the wedges whose runs are not complete
/// and which no job is running or queued for, and a new report after it. Each resumes from
/// its run's newest checkpoint, so nothing already simulated is redone. A plan written with
/// `--dry-run` is submitted as it is.
pub fn resubmit(farm_dir: &Path, dry_run: bool) -> Result<Submitted> {
    let farm_dir = farm_dir
        .canonicalize()
        .map_err(|e| Error::InvalidInput(format!("{}: {e}", farm_dir.display())))?;
    let mut plan = FarmPlan::load(&farm_dir)?;
    if plan.backend == Backend::OpenJd.name() {
        let template = farm_dir.join(openjd::TEMPLATE);
        return Err(Error::InvalidInput(format!(
            "{}: an Open Job Description farm (--backend openjd) is not resubmitted by nimbus: \
             retry its failed tasks in the farm manager, or run it again here with `openjd run {} --step \
             Report --run-dependencies`; either way the wedges resume from their checkpoints",
            farm_dir.display(),
            slurm::sh(&template.to_string_lossy())
        )));
    }
    // A --dry-run plan (nothing submitted yet) is submitted as it was written.
    if plan.jobs.iter().all(|j| j.slurm_id.is_none()) {
        return write_and_submit(plan, farm_dir, dry_run, 0);
    }
    let status = super::status::collect(&plan, &farm_dir);
    if let Some(err) = &status.scheduler_error {
        if !dry_run {
            return Err(Error::Runtime(err.clone()));
        }
    }
    let active: Vec<&str> = ["pending", "running", "requeued"].to_vec();
    if let Some(w) = status
        .wedges
        .iter()
        .find(|w| active.contains(&w.state.as_str()))
    {
        return Err(Error::InvalidInput(format!(
            "{}: wedge {} is still {} (job {}); wait for it or scancel it first",
            farm_dir.display(),
            w.name,
            w.state,
            w.job.as_deref().unwrap_or("?")
        )));
    }
    let tasks: Vec<usize> = status
        .wedges
        .iter()
        .filter(|w| w.state != "done")
        .map(|w| w.index)
        .collect();
    if tasks.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: every wedge is complete; nothing to resubmit",
            farm_dir.display()
        )));
    }
    let round = plan
        .jobs
        .iter()
        .filter(|j| j.kind == JobKind::Simulation)
        .count()
        + 1;
    let first = plan.jobs.len();
    add_jobs(&mut plan, &tasks, &format!(".{round}"));
    write_and_submit(plan, farm_dir, dry_run, first)
}

/// The export stage of `--export-chunk`: refused (exit 2) before anything is written when a
/// setting is not an `export.*` key nimbus export may change, does not validate for a wedge, or
/// leaves a wedge's own export settings (the simulation already writes those files).
fn export_settings(
    opts: &SubmitOptions,
    wedges: &[wedge::Wedge],
) -> Result<Option<ExportSettings>> {
    let Some(chunk) = opts.export_chunk else {
        if !opts.export_sets.is_empty() || opts.export_name.is_some() {
            return Err(Error::InvalidInput(
                "--export-set and --export-name need --export-chunk N (frames per export task)"
                    .into(),
            ));
        }
        return Ok(None);
    };
    if chunk == 0 {
        return Err(Error::InvalidInput(
            "--export-chunk 0: give the frames per export task (1 or more)".into(),
        ));
    }
    if opts.export_sets.is_empty() {
        return Err(Error::InvalidInput(
            "--export-chunk needs at least one --export-set export.KEY=VALUE: with the run's own              export settings the simulation writes those files itself"
                .into(),
        ));
    }
    crate::pipeline::reexport::check_sets(&opts.export_sets)
        .map_err(|e| Error::InvalidInput(e.to_string().replace("--set ", "--export-set ")))?;
    if let Some(n) = &opts.export_name {
        crate::pipeline::reexport::check_name(n)
            .map_err(|e| Error::InvalidInput(e.to_string().replace("--name", "--export-name")))?;
    }
    for w in wedges {
        let sets = w.sets();
        let own = crate::shot::load(&opts.config, &sets)?.into_config();
        let mut with = sets.clone();
        with.extend(opts.export_sets.iter().cloned());
        let other = crate::shot::load(&opts.config, &with)?.into_config();
        if other.export == own.export {
            return Err(Error::InvalidInput(format!(
                "--export-set {}: leaves the export settings of wedge {} as they are; the                  simulation writes those files itself",
                opts.export_sets.join(" --export-set "),
                w.name
            )));
        }
    }
    Ok(Some(ExportSettings {
        chunk,
        sets: opts.export_sets.clone(),
        name: opts.export_name.clone(),
    }))
}

/// Blender and the render script: found now, so a farm never fails on them hours later.
fn render_settings(frame_padding: u32) -> Result<RenderSettings> {
    let blender = find_on_path("blender").ok_or_else(|| {
        Error::Runtime(
            "--render: blender not found on PATH: install it (tools/setup.sh --blender)".into(),
        )
    })?;
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/render_blender.py");
    let script = std::env::var_os("NIMBUS_RENDER_SCRIPT")
        .map(PathBuf::from)
        .unwrap_or(script);
    if !script.is_file() {
        return Err(Error::Runtime(format!(
            "--render: {} not found (set NIMBUS_RENDER_SCRIPT to tools/render_blender.py)",
            script.display()
        )));
    }
    Ok(RenderSettings {
        blender,
        script,
        frame_padding,
    })
}

fn find_on_path(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join(name))
            .find(|p| p.is_file())
    })
}

/// Seconds of a Slurm `--time` value: `M`, `M:S`, `H:M:S`, `D-H`, `D-H:M`, `D-H:M:S`.
pub(crate) fn time_limit_seconds(t: &str) -> Result<u64> {
    let bad = || {
        Error::InvalidInput(format!(
            "--time-limit {t:?}: expected minutes, MM:SS, HH:MM:SS or D-HH[:MM[:SS]] (Slurm's --time)"
        ))
    };
    let num = |s: &str| -> Result<u64> {
        if s.is_empty() || !s.chars().all(|c| c.is_ascii_digit()) {
            return Err(bad());
        }
        s.parse().map_err(|_| bad())
    };
    let (days, rest) = match t.split_once('-') {
        Some((d, r)) => (Some(num(d)?), r),
        None => (None, t),
    };
    let parts = rest.split(':').map(num).collect::<Result<Vec<u64>>>()?;
    let secs = match (days, parts.as_slice()) {
        (None, [m]) => m * 60,
        (None, [m, s]) => m * 60 + s,
        (None, [h, m, s]) | (Some(_), [h, m, s]) => h * 3600 + m * 60 + s,
        (Some(_), [h]) => h * 3600,
        (Some(_), [h, m]) => h * 3600 + m * 60,
        _ => return Err(bad()),
    };
    Ok(days.unwrap_or(0) * 86_400 + secs)
}

/// The time limit must leave the simulation its margin, or every job would be told to stop
/// as soon as it starts.
fn check_time_limit(t: &str, margin_s: u32) -> Result<()> {
    let secs = time_limit_seconds(t)?;
    if secs <= margin_s as u64 {
        return Err(Error::InvalidInput(format!(
            "--time-limit {t} ({secs} s) must be longer than --signal-margin ({margin_s} s)"
        )));
    }
    Ok(())
}

fn make_executable(path: &Path) -> Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755))
            .map_err(|e| Error::io(path, e))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{check_time_limit, time_limit_seconds};

    #[test]
    fn time_limits_in_slurm_formats() {
        for (t, secs) in [
            ("30", 1800),
            ("10:00", 600),
            ("1:00:00", 3600),
            ("2-12", 216_000),
            ("1-0:30", 88_200),
            ("1-00:00:01", 86_401),
        ] {
            assert_eq!(time_limit_seconds(t).unwrap(), secs, "{t}");
        }
        for bad in ["", "1h", "1:2:3:4", "-1", "a-1", "1-", "1-2:3:4:5"] {
            assert!(time_limit_seconds(bad).is_err(), "{bad}");
        }
        assert!(check_time_limit("2", 120).is_err());
        assert!(check_time_limit("3", 120).is_ok());
    }
}
