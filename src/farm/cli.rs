//! `nimbus farm ...`: the subcommands' arguments and what each prints.
use super::status;
use super::submit::{self, Backend, SubmitOptions, Submitted, DEFAULT_SIGNAL_MARGIN_S};
use crate::error::{Error, Result};
use crate::pipeline::LogFormat;
use clap::Subcommand;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum FarmCommand {
    /// Write a farm directory (farm.json plan + sbatch scripts) for a shot and its wedges, and
    /// submit it to Slurm: a simulation job array (one task per wedge, requeued at the time
    /// limit until complete), an optional export array over frame chunks, an optional Blender
    /// render array, and a report job. With `--backend openjd`: the same plan as an Open Job
    /// Description template (AWS Deadline Cloud), run here with `--run-local`.
    Submit {
        /// Shot config (YAML).
        config: PathBuf,
        /// `slurm` (batch scripts submitted with sbatch) or `openjd` (an Open Job Description
        /// template, `FARM/template.json`, for AWS Deadline Cloud or `openjd run`).
        #[arg(
            long,
            value_enum,
            value_name = "slurm|openjd",
            default_value = "slurm",
            hide_possible_values = true
        )]
        backend: Backend,
        /// With `--backend openjd`: run the template here with `openjd run` (every step, in
        /// order; `openjd` on PATH or NIMBUS_OPENJD), output in FARM/logs/openjd_run.log.
        #[arg(long)]
        run_local: bool,
        /// Wedge a key over values, e.g. `--wedge physics.heat_source=0.2,0.3`; each --wedge
        /// multiplies the combinations (repeatable).
        #[arg(long = "wedge", value_name = "KEY=V1,V2,...")]
        wedge: Vec<String>,
        /// Farm directory (default: `<shot>_farm`); wedge runs go to its runs/.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Slurm partition of every job (default: the cluster's default partition; Slurm only).
        #[arg(long)]
        partition: Option<String>,
        /// Slurm time limit of each job (`--time`: minutes, MM:SS, HH:MM:SS, D-HH...). A
        /// simulation longer than this goes on in its next job. With `--backend openjd`: the
        /// Simulation action's timeout (this minus --signal-margin, in seconds).
        #[arg(long, value_name = "T")]
        time_limit: Option<String>,
        /// Seconds before the time limit at which a simulation is told to checkpoint and stop
        /// (`--signal=B:TERM@SECS`; with `--backend openjd` the cancelation notice,
        /// `notifyPeriodInSeconds`, at most 600).
        #[arg(long, value_name = "SECS", default_value_t = DEFAULT_SIGNAL_MARGIN_S)]
        signal_margin: u32,
        /// Times a simulation task is requeued after being killed (a lost node, kill -9) before
        /// it is reported failed (Slurm only: OpenJD farm managers set task retries on the
        /// queue or job).
        #[arg(long, value_name = "N", default_value_t = 1)]
        crash_requeues: u32,
        /// Also render every frame of every wedge with Blender (tools/render_blender.py) to
        /// `<run>/render/<shot>.<frame>.png`.
        #[arg(long)]
        render: bool,
        /// Add an export stage: `nimbus export RUN --frames A-B` as a job array over chunks of N
        /// frames of every wedge, each chunk starting as soon as the manifest records its frames
        /// (the simulation then writes particle caches: `export.particles=true`). Needs
        /// --export-set.
        #[arg(long, value_name = "N")]
        export_chunk: Option<u32>,
        /// An export setting of the export stage, e.g. `--export-set export.voxel_size=12.5`
        /// (`nimbus export --set`; `export.*` keys, not export.particles; repeatable). The files
        /// go to each run's `exports/<name>/`.
        #[arg(long = "export-set", value_name = "export.KEY=VALUE")]
        export_set: Vec<String>,
        /// Name of the export directory (`nimbus export --name`; default: a hash of the
        /// settings).
        #[arg(long, value_name = "NAME")]
        export_name: Option<String>,
        /// Write the farm directory and print the sbatch commands, submit nothing (`--backend
        /// openjd` submits nothing anyway).
        #[arg(long)]
        dry_run: bool,
    },
    /// The state of every job and wedge of a farm (pending, running, requeued, done, failed)
    /// and the frames done per wedge.
    Status {
        farm_dir: PathBuf,
        /// `human` (a table) or `json` (one JSON document, for pipeline tools).
        #[arg(long, value_enum, default_value = "human")]
        log_format: LogFormat,
    },
    /// Submit again the wedges that failed (they resume from their checkpoints) and a new
    /// report; a plan written with `submit --dry-run` is submitted as it is.
    Resubmit {
        farm_dir: PathBuf,
        /// Write the new scripts into the plan and print the sbatch commands, submit nothing.
        #[arg(long)]
        dry_run: bool,
    },
    /// Check every wedge's frames against its manifest (sizes, SHA-256) and write
    /// farm_report.json and the wedge contact sheet (the farm's last job runs this).
    /// Exits 0 when the farm is complete, 3 when it is not.
    Report { farm_dir: PathBuf },
}

pub fn run(cmd: FarmCommand) -> Result<()> {
    match cmd {
        FarmCommand::Submit {
            config,
            backend,
            run_local,
            wedge,
            out,
            partition,
            time_limit,
            signal_margin,
            crash_requeues,
            render,
            export_chunk,
            export_set,
            export_name,
            dry_run,
        } => {
            let done = submit::submit(&SubmitOptions {
                config,
                backend,
                run_local,
                wedges: wedge,
                out,
                partition,
                time_limit,
                signal_margin_s: signal_margin,
                crash_requeues,
                render,
                export_chunk,
                export_sets: export_set,
                export_name,
                dry_run,
            })?;
            print_submitted(&done, dry_run);
            Ok(())
        }
        FarmCommand::Resubmit { farm_dir, dry_run } => {
            let done = submit::resubmit(&farm_dir, dry_run)?;
            print_submitted(&done, dry_run);
            Ok(())
        }
        FarmCommand::Status {
            farm_dir,
            log_format,
        } => {
            let plan = super::plan::FarmPlan::load(&farm_dir)?;
            let s = status::collect(&plan, &farm_dir);
            match log_format {
                LogFormat::Json => crate::outln!(
                    "{}",
                    serde_json::to_string(&s).map_err(|e| Error::Runtime(e.to_string()))?
                ),
                LogFormat::Human => {
                    let text = status::render_text(&s);
                    crate::outln!("{}", text.strip_suffix('\n').unwrap_or(&text))
                }
            }
            match s.scheduler_error {
                Some(e) => Err(Error::Runtime(e)),
                None => Ok(()),
            }
        }
        FarmCommand::Report { farm_dir } => {
            let r = super::report::report(&farm_dir)?;
            for w in &r.wedges {
                crate::outln!(
                    "{}: {}/{} frames verified{}",
                    w.name,
                    w.frames_verified,
                    w.frames_expected,
                    if w.complete { "" } else { " (incomplete)" }
                );
            }
            crate::outln!(
                "report: {} (complete: {})",
                farm_dir.join(super::plan::REPORT).display(),
                r.complete
            );
            if r.complete {
                Ok(())
            } else {
                Err(Error::Runtime(format!(
                    "the farm is not complete: see {}",
                    farm_dir.join(super::plan::REPORT).display()
                )))
            }
        }
    }
}

fn print_submitted(done: &Submitted, dry_run: bool) {
    crate::outln!(
        "farm {}: shot '{}', {} wedge(s)",
        done.farm_dir.display(),
        done.plan.shot,
        done.plan.wedges.len()
    );
    for w in &done.plan.wedges {
        crate::outln!("  {}  {}", w.name, w.label());
    }
    if let Some(t) = &done.template {
        print_openjd(done, t);
        return;
    }
    for (name, line, id) in &done.jobs {
        match id {
            Some(id) => crate::outln!("submitted {name}: job {id}"),
            None => crate::outln!("{name}: {line}"),
        }
    }
    if dry_run {
        crate::outln!(
            "dry run: nothing submitted; the plan is in {}",
            done.farm_dir.join(super::plan::PLAN).display()
        );
    } else {
        crate::outln!(
            "follow it with: nimbus farm status {}",
            super::slurm::sh(&done.farm_dir.to_string_lossy())
        );
    }
}

fn print_openjd(done: &Submitted, template: &std::path::Path) {
    use super::slurm::sh;
    for (name, command, _) in &done.jobs {
        crate::outln!("{name}: {command}");
    }
    let t = sh(&template.to_string_lossy());
    crate::outln!(
        "wrote the Open Job Description template: {}",
        template.display()
    );
    match &done.local_run {
        Some(r) => {
            crate::outln!(
                "ran it here in {:.1} s: {} (log: {})",
                r.seconds,
                r.command
                    .iter()
                    .map(|a| sh(a))
                    .collect::<Vec<_>>()
                    .join(" "),
                r.log.display()
            );
            crate::outln!(
                "report: {}",
                done.farm_dir.join(super::plan::REPORT).display()
            );
        }
        None => {
            crate::outln!("check it: openjd check {t}");
            crate::outln!("run it here: openjd run {t} --step Report --run-dependencies");
            crate::outln!(
                "submit it to AWS Deadline Cloud (a job bundle): deadline bundle submit {}",
                sh(&template.parent().unwrap_or(template).to_string_lossy())
            );
        }
    }
}
