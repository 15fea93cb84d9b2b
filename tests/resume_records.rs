//! Resume from checkpoints alone, and refusals that name the keys (issue 13 case 8).
mod common;
use common::*;
use std::path::Path;

fn crash_at(out: &Path, fault: &str) {
    let o = nimbus()
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(out)
        .args(["--log-format", "json"])
        .env("NIMBUS_FAULT", fault)
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
}

fn resume(out: &Path) -> std::process::Output {
    nimbus()
        .arg("resume")
        .arg(out)
        .args(["--log-format", "json"])
        .output()
        .unwrap()
}

#[test]
fn a_run_whose_manifest_was_lost_resumes_from_its_checkpoints() {
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("ref");
    let o = run_tiny(&reference, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let out = dir.path().join("run");
    crash_at(&out, "frame:6");
    std::fs::remove_file(out.join("manifest.json")).unwrap();
    // Without the manifest the frame files are still known as the run's: not foreign.
    let o = run_tiny(&out, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("already holds a nimbus run"));
    let o = resume(&out);
    assert!(o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("rebuilt from the files on disk"), "{err}");
    assert_eq!(checksums(&out), checksums(&reference));
    assert_eq!(
        stats_without_timings(&out),
        stats_without_timings(&reference)
    );
    assert!(manifest(&out)["complete"].as_bool().unwrap());
}

#[test]
fn a_resume_refused_over_changed_simulation_keys_names_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    crash_at(&out, "frame:4");
    let mut m = manifest(&out);
    m["config"]["seed"] = 99.into();
    m["config"]["solver"]["iterations"] = 5.into();
    std::fs::write(
        out.join("manifest.json"),
        serde_json::to_string(&m).unwrap(),
    )
    .unwrap();
    let o = resume(&out);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    let last = err.lines().last().unwrap();
    assert!(
        last.contains("simulation keys differ")
            && last.contains("seed")
            && last.contains("solver.iterations"),
        "{err}"
    );
}

/// `run CONFIG --resume` also works without the manifest, and still names changed keys.
#[test]
fn run_resume_without_a_manifest_uses_the_checkpoint_config() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    crash_at(&out, "frame:4");
    std::fs::remove_file(out.join("manifest.json")).unwrap();
    let o = run_tiny(&out, &["--resume", "--set", "seed=4"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("seed"),
        "{}",
        text(&o)
    );
    let o = run_tiny(&out, &["--resume"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(manifest(&out)["complete"].as_bool().unwrap());
    assert_eq!(manifest(&out)["frames"].as_array().unwrap().len(), 8);
}
