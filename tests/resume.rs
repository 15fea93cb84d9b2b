//! Checkpoint and resume through the real binary: a run killed anywhere and resumed writes the
//! same bytes as an uninterrupted run; bad checkpoints are skipped; a full disk fails cleanly.
mod common;
use common::*;
use std::path::Path;

/// The uninterrupted reference run (kept on disk), its file checksums and stats without timings.
type Reference = (tempfile::TempDir, Vec<Checksum>, Vec<serde_json::Value>);

/// The uninterrupted reference run, shared by the tests of this file.
fn reference() -> &'static Reference {
    static R: std::sync::OnceLock<Reference> = std::sync::OnceLock::new();
    R.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ref");
        let o = run_tiny(&out, &[]);
        assert!(o.status.success(), "{}", text(&o));
        let sums = checksums(&out);
        let stats = stats_without_timings(&out);
        (dir, sums, stats)
    })
}

/// `nimbus run samples/tiny.yaml` into `out`, aborted at the `NIMBUS_FAULT` point `fault`.
fn run_with_fault(out: &Path, fault: &str) -> std::process::Output {
    let mut c = nimbus();
    c.arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(out)
        .args(["--log-format", "json"]);
    c.env("NIMBUS_FAULT", fault).output().unwrap()
}

fn resume(out: &Path) -> std::process::Output {
    nimbus()
        .arg("resume")
        .arg(out)
        .arg("--log-format")
        .arg("json")
        .output()
        .unwrap()
}

/// Kill the run (abort, like SIGKILL) at `fault`, resume, compare with the reference.
fn crash_and_resume(fault: &str) {
    let (_keep, ref_sums, ref_stats) = reference();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = run_with_fault(&out, fault);
    assert!(
        !o.status.success(),
        "the fault {fault} did not stop the run: {}",
        text(&o)
    );
    let r = resume(&out);
    assert!(r.status.success(), "resume after {fault}: {}", text(&r));
    assert_eq!(&checksums(&out), ref_sums, "files differ after {fault}");
    assert_eq!(
        &stats_without_timings(&out),
        ref_stats,
        "stats differ after {fault}"
    );
}

#[test]
fn killed_while_simulating_a_frame() {
    crash_and_resume("frame:4");
}

#[test]
fn killed_while_writing_a_frame() {
    crash_and_resume("rename:.vdb:5");
}

#[test]
fn killed_while_writing_a_checkpoint() {
    crash_and_resume("rename:ckpt_:2");
}

#[test]
fn sigint_checkpoints_exits_130_and_resumes() {
    let (_keep, ref_sums, _) = reference();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let child = nimbus()
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&out)
        .arg("--log-format")
        .arg("json")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Interrupt once the first frame is on disk.
    let t0 = std::time::Instant::now();
    while !out.join("stats.jsonl").exists() && t0.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    kill(child.id(), "INT");
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    // The signal comes after frame 1 of 8 (each takes a good fraction of a second here).
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("nimbus resume"), "no resume command in: {err}");
    let r = resume(&out);
    assert!(r.status.success(), "{}", text(&r));
    assert_eq!(&checksums(&out), ref_sums);
}

#[test]
fn corrupt_newest_checkpoint_falls_back_to_the_previous() {
    let (_keep, ref_sums, _) = reference();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    assert!(!run_with_fault(&out, "frame:6").status.success());
    let mut cks: Vec<_> = std::fs::read_dir(out.join("checkpoints"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    cks.sort();
    assert!(cks.len() >= 2, "need two checkpoints, have {cks:?}");
    let newest = cks.last().unwrap();
    let mut bytes = std::fs::read(newest).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    std::fs::write(newest, bytes).unwrap();
    let r = resume(&out);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(r.status.success(), "{}", text(&r));
    assert!(
        err.contains(&newest.file_name().unwrap().to_string_lossy().to_string()),
        "skipped file not named: {err}"
    );
    assert_eq!(&checksums(&out), ref_sums);
}

#[test]
fn resume_without_a_usable_checkpoint_is_invalid_input() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    assert!(!run_with_fault(&out, "frame:2").status.success());
    for e in std::fs::read_dir(out.join("checkpoints"))
        .unwrap()
        .flatten()
    {
        std::fs::write(e.path(), b"garbage").unwrap();
    }
    let r = resume(&out);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("no usable checkpoint"), "{err}");
}

#[test]
fn resume_of_a_directory_that_is_no_run_is_invalid_input() {
    let dir = tempfile::tempdir().unwrap();
    let r = resume(dir.path());
    assert_eq!(r.status.code(), Some(2), "{}", text(&r));
}

#[test]
fn changed_simulation_keys_are_refused_with_their_names() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    assert!(!run_with_fault(&out, "frame:3").status.success());
    let o = run_tiny(
        &out,
        &[
            "--resume",
            "--set",
            "solver.iterations=7",
            "--set",
            "physics.buoyancy=1.5",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("solver.iterations") && err.contains("physics.buoyancy"),
        "{err}"
    );
    // Output-only keys may change.
    let o = run_tiny(&out, &["--resume", "--set", "export.vdb.compression=zip"]);
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn a_full_disk_fails_with_exit_3_and_keeps_finished_work() {
    // A small tmpfs needs mount rights (root in CI); skip elsewhere.
    let dir = tempfile::tempdir().unwrap();
    let mnt = dir.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let ok = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=160k", "tmpfs"])
        .arg(&mnt)
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !ok {
        eprintln!("skipped: cannot mount a tmpfs here");
        return;
    }
    let out = mnt.join("run");
    let o = run_tiny(&out, &[]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    // Whatever the manifest lists is complete and intact; no temporary file is left.
    let listed_intact = !out.join("manifest.json").exists()
        || checksums(&out).iter().all(|(_, p, sum)| {
            std::fs::read(out.join(p))
                .map(|b| nimbus::pipeline::records::sha256_hex(&b) == *sum)
                .unwrap_or(false)
        });
    let leftovers = std::process::Command::new("find")
        .arg(&out)
        .args(["-name", "*.nimbus-tmp"])
        .output()
        .unwrap()
        .stdout;
    let _ = std::process::Command::new("umount").arg(&mnt).status();
    assert_eq!(o.status.code(), Some(3), "{err}");
    let last = err.lines().last().unwrap_or("");
    assert!(last.contains("No space left"), "{last}");
    assert!(listed_intact, "a frame listed in the manifest is damaged");
    assert!(
        leftovers.is_empty(),
        "temporary files left: {}",
        String::from_utf8_lossy(&leftovers)
    );
}
