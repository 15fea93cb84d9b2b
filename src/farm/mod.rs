//! The farm: many variants (wedges) of a shot and their per-frame work, run on an existing
//! scheduler (Slurm), or written as an Open Job Description template (AWS Deadline Cloud). A simulation cannot be split across nodes, but it can be cut into time
//! segments at checkpoints: each wedge's job resumes where the last one stopped, so a shot longer
//! than the partition's time limit finishes across several jobs.
//!
//! - [`wedge`]: `--wedge key=v1,v2` options, their combinations, names and validation.
//! - [`cli`]: the `nimbus farm` subcommands.
//! - [`plan`]: `farm.json`, every job with its script, dependencies and Slurm id.
//! - [`slurm`]: the batch scripts, `sbatch` and `squeue`.
//! - [`openjd`]: the Open Job Description backend: the plan as one job template (AWS
//!   Deadline Cloud), run here with `openjd run`.
//! - [`submit`]: `farm submit` / `farm resubmit`.
//! - [`status`]: `farm status`.
//! - [`report`] and [`sheet`]: the report job (`farm_report.json`, wedge contact sheet).
pub mod cli;
pub mod openjd;
pub mod plan;
pub mod report;
pub mod sheet;
pub mod slurm;
pub mod status;
pub mod submit;
pub mod wedge;
