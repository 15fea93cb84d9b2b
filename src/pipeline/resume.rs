//! The resume policy: the config a run resumes with (its manifest's, or its newest checkpoint's
//! when the manifest is lost) and the refusal of changed simulation keys (the checkpoint it
//! resumes from is `super::checkpoints`'). `nimbus resume` and `nimbus run --resume` are
//! [`resume`] and [`resume_with`], so a library caller gets the same refusals as the command
//! line.
use super::lock::{Create, RunLock};
use super::open::{RunOptions, Start};
use super::progress::LogFormat;
use super::records::Manifest;
use super::run::run;
use super::run_dir::RunDir;
use crate::config::{self, ShotConfig};
use crate::error::{Error, Result};
use crate::io::checkpoint;
use crate::shot::Shot;
use std::path::Path;

/// `nimbus resume OUT_DIR`: goes on with the run in `out_dir`, with the config it recorded.
pub fn resume(out_dir: &Path, log: LogFormat) -> Result<()> {
    let lock = RunLock::acquire(out_dir, Create::No, "resume")?;
    let shot = recorded_shot(out_dir)?;
    run(&shot, &resume_options(out_dir, log), &lock)
}

/// `nimbus run CONFIG --resume`: goes on with the run in `out_dir` with `shot`, refused when
/// one of its simulation keys differs from the run's (output-only keys may change).
pub fn resume_with(shot: &Shot, out_dir: &Path, log: LogFormat) -> Result<()> {
    let lock = RunLock::acquire(out_dir, Create::No, "run")?;
    refuse_changed_simulation(shot.config(), out_dir)?;
    run(shot, &resume_options(out_dir, log), &lock)
}

fn resume_options(out_dir: &Path, log: LogFormat) -> RunOptions {
    RunOptions {
        out_dir: out_dir.to_path_buf(),
        log,
        start: Start::Resume,
        device: None,
    }
}

/// The shot of the resolved config a run recorded in its manifest, with overrides applied
/// (JSON is YAML).
pub fn shot_of_run(out_dir: &Path, set: &[String]) -> Result<Shot> {
    let run = RunDir::new(out_dir);
    let manifest = Manifest::load(&run)?;
    let text = serde_json::to_string_pretty(&manifest.config)
        .map_err(|e| Error::Runtime(e.to_string()))?;
    let origin = run.manifest();
    crate::shot::load_str(&text, &origin.to_string_lossy(), set)
}

/// The run's shot: its manifest's config, or its newest checkpoint's when the manifest is lost.
pub fn recorded_shot(out_dir: &Path) -> Result<Shot> {
    if RunDir::new(out_dir).manifest().exists() {
        shot_of_run(out_dir, &[])
    } else {
        shot_of_checkpoints(out_dir)
    }
}

/// The shot of the config recorded in the newest valid checkpoint (a run whose manifest.json
/// was lost).
fn shot_of_checkpoints(out_dir: &Path) -> Result<Shot> {
    let run = RunDir::new(out_dir);
    let Some((path, cfg)) = checkpoint::newest_config(&run.checkpoints())? else {
        return Err(Error::InvalidInput(format!(
            "{}: not a nimbus run directory: no manifest.json, and no checkpoint that records its config",
            out_dir.display()
        )));
    };
    // Loaded through validation like any config; the checkpoint names it in errors.
    let text = serde_json::to_string_pretty(&cfg).map_err(|e| Error::Runtime(e.to_string()))?;
    let shot = crate::shot::load_str(&text, &path.to_string_lossy(), &[])?;
    eprintln!(
        "note: {} is missing; resuming with the config recorded in {}",
        run.manifest().display(),
        path.display()
    );
    Ok(shot)
}

/// Refuses `cfg` for resuming the run in `out_dir` when its simulation keys differ from the
/// run's recorded config, naming every key that differs.
pub fn refuse_changed_simulation(cfg: &ShotConfig, out_dir: &Path) -> Result<()> {
    let recorded = recorded_shot(out_dir)?;
    let diff = config::sim_key_diff(recorded.config(), cfg);
    if diff.is_empty() {
        Ok(())
    } else {
        Err(Error::InvalidInput(format!(
            "{}: cannot resume: simulation keys differ from the run's: {}",
            out_dir.display(),
            diff.join(", ")
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::checkpoint::{write_checkpoint, Checkpoint, CheckpointHeader, CONFIG_SECTION};

    fn tiny(set: &[&str]) -> Shot {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny.yaml");
        let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        crate::shot::load(&path, &set).unwrap()
    }

    /// A run directory whose manifest was lost: one checkpoint that records `cfg`.
    fn checkpoint_only_run(cfg: &ShotConfig) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let ck = Checkpoint {
            header: CheckpointHeader {
                tool_version: crate::VERSION.into(),
                sim_hash: config::sim_hash(cfg),
                frame: 4,
                step: 40,
                time: 1.0,
                seed: cfg.seed,
                particle_count: 0,
                capacity: 0,
                adapter: "none".into(),
                next_id: 0,
            },
            state: Default::default(),
            extra: [(CONFIG_SECTION.into(), serde_json::to_vec(cfg).unwrap())].into(),
        };
        write_checkpoint(&RunDir::new(dir.path()).checkpoints(), &ck).unwrap();
        dir
    }

    #[test]
    fn a_library_resume_is_refused_like_the_command_line() {
        let cfg = tiny(&[]).into_config();
        let run = checkpoint_only_run(&cfg);
        let recorded = recorded_shot(run.path()).unwrap();
        assert!(config::sim_key_diff(recorded.config(), &cfg).is_empty());
        // Every changed simulation key is named, before the GPU is opened.
        let changed = tiny(&["seed=9", "physics.heat_source=0.31", "output.frames.end=5"]);
        let e = resume_with(&changed, run.path(), LogFormat::Json).unwrap_err();
        assert!(matches!(e, Error::InvalidInput(_)), "{e:?}");
        assert!(
            e.to_string()
                .ends_with("simulation keys differ from the run's: physics.heat_source, seed"),
            "{e}"
        );
        let empty = tempfile::tempdir().unwrap();
        let e = resume(empty.path(), LogFormat::Json).unwrap_err();
        assert!(e.to_string().contains("not a nimbus run directory"), "{e}");
    }
}
