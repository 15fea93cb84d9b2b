//! Run directories never lose work (issue 13): `run` never clobbers a run, `--force` removes
//! only nimbus's own files, foreign files are never deleted, and an exclusive lock keeps two
//! real processes off one directory.
mod common;
use common::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Output, Stdio};
use std::time::{Duration, Instant};

/// Every file under `dir` with its bytes' SHA-256 (the lock file, emptied on exit, left out).
fn tree(dir: &Path) -> BTreeMap<PathBuf, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.file_name().unwrap() != ".lock" {
                let sum = nimbus::pipeline::records::sha256_hex(&std::fs::read(&p).unwrap());
                out.insert(p.strip_prefix(dir).unwrap().to_path_buf(), sum);
            }
        }
    }
    out
}

/// `nimbus run` of the tiny sample into `out`, stderr piped.
fn tiny_command(out: &Path, extra: &[&str]) -> std::process::Command {
    let mut c = nimbus();
    c.arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(out)
        .args(["--log-format", "json"])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    c
}

fn spawn_tiny(out: &Path, extra: &[&str]) -> Child {
    tiny_command(out, extra).spawn().unwrap()
}

fn resume(out: &Path) -> std::process::Command {
    let mut c = nimbus();
    c.arg("resume").arg(out).args(["--log-format", "json"]);
    c
}

/// Waits until `n` lines are in stats.jsonl (n frames on disk).
fn wait_frames(out: &Path, n: usize) {
    let t0 = Instant::now();
    while std::fs::read_to_string(out.join("stats.jsonl"))
        .map(|t| t.lines().count())
        .unwrap_or(0)
        < n
    {
        assert!(
            t0.elapsed().as_secs() < 120,
            "no frame {n} in {}",
            out.display()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// Case 1 of the issue: a run into a directory holding an interrupted run is refused with both
/// ways forward, and changes nothing; the run is then resumed to the same bytes as a run never
/// interrupted.
#[test]
fn run_into_a_run_is_refused_and_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("ref");
    let o = run_tiny(&reference, &[]);
    assert!(o.status.success(), "{}", text(&o));

    let out = dir.path().join("d");
    let child = spawn_tiny(&out, &[]);
    wait_frames(&out, 3);
    kill(child.id(), "INT");
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    let before = tree(&out);

    for extra in [&[][..], &["--set", "shot=other"][..]] {
        let o = run_tiny(&out, extra);
        assert_eq!(o.status.code(), Some(2), "{}", text(&o));
        let err = stderr(&o);
        assert!(err.contains(&out.display().to_string()), "{err}");
        assert!(
            err.contains(&format!("nimbus resume {}", out.display())),
            "{err}"
        );
        assert!(err.contains("--force"), "{err}");
        assert_eq!(tree(&out), before, "a refused run changed the directory");
    }
    let o = resume(&out).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(checksums(&out), checksums(&reference));
}

#[test]
fn force_removes_only_the_runs_own_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d");
    let o = run_tiny(&out, &["--set", "output.frames.end=4"]);
    assert!(o.status.success(), "{}", text(&o));
    // An unlisted frame of the run (as a kill between file and manifest leaves) is its own too.
    std::fs::write(out.join("vdb/tiny.0005.vdb"), b"partial").unwrap();
    let o = run_tiny(&out, &["--force", "--set", "output.frames.end=2"]);
    assert!(o.status.success(), "{}", text(&o));
    let files: Vec<String> = tree(&out)
        .keys()
        .map(|p| p.to_string_lossy().to_string())
        .filter(|p| p.starts_with("vdb/"))
        .collect();
    assert_eq!(files, ["vdb/tiny.0001.vdb", "vdb/tiny.0002.vdb"]);
    assert_eq!(manifest(&out)["frames"].as_array().unwrap().len(), 2);
}

#[test]
fn foreign_files_are_never_deleted_and_refuse_the_directory() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d");
    let o = run_tiny(&out, &["--set", "output.frames.end=2"]);
    assert!(o.status.success(), "{}", text(&o));
    for (rel, body) in [
        ("checkpoints/notes.txt", &b"mine"[..]),
        ("checkpoints/ckpt_000099.nck", &b"not a checkpoint"[..]),
        ("vdb/other_shot.0001.vdb", &b"x"[..]),
    ] {
        std::fs::write(out.join(rel), body).unwrap();
        let before = tree(&out);
        for extra in [&[][..], &["--force"][..]] {
            let o = run_tiny(&out, extra);
            assert_eq!(o.status.code(), Some(2), "{}", text(&o));
            assert!(stderr(&o).contains(rel), "{}", text(&o));
            assert_eq!(tree(&out), before);
        }
        std::fs::remove_file(out.join(rel)).unwrap();
    }
    // A manifest.json nimbus did not write is foreign too.
    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("manifest.json"), b"{\"mine\": true}").unwrap();
    let o = run_tiny(&other, &["--force"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert_eq!(
        std::fs::read(other.join("manifest.json")).unwrap(),
        b"{\"mine\": true}"
    );
}

#[test]
fn out_pointing_at_a_file_is_invalid_input() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("file");
    std::fs::write(&f, b"x").unwrap();
    let o = run_tiny(&f, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert_eq!(std::fs::read(&f).unwrap(), b"x");
    let o = resume(&dir.path().join("missing")).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}

/// Two real processes on one directory: while a run holds it, a second run (even with --force),
/// a resume and a preview exit 2 naming the holder's pid, and touch nothing (not even a
/// temporary file). SIGHUP then stops the run like SIGTERM (checkpoint, exit 130); of two
/// resumes started together exactly one runs, and the result matches an uninterrupted run.
#[test]
fn two_processes_on_one_directory() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d");
    let long = ["--set", "output.frames.end=60"];
    // slowed (0.5 s a frame, same output) so that it still runs while the five refused
    // processes start one after the other: unslowed it could finish first on a fast adapter
    let child = tiny_command(&out, &long)
        .env("NIMBUS_FAULT", "slow:500")
        .spawn()
        .unwrap();
    let pid = child.id();
    wait_frames(&out, 1);
    let planted = out.join("vdb/tiny.0001.vdb.1-0000000000000000.nimbus-tmp");
    std::fs::write(&planted, b"a live writer's temp").unwrap();
    let host = nimbus::pipeline::lock::host_name();
    let want = format!("in use by pid {pid} (host {host})");
    let second = [
        run_tiny(&out, &long),
        run_tiny(&out, &["--force"]),
        run_tiny(&out, &["--resume"]),
        resume(&out).output().unwrap(),
        nimbus().arg("preview").arg(&out).output().unwrap(),
    ];
    let lock_text = std::fs::read_to_string(out.join(".lock")).unwrap();
    kill(pid, "HUP");
    let first = child.wait_with_output().unwrap();
    for (i, o) in second.iter().enumerate() {
        assert_eq!(o.status.code(), Some(2), "second process {i}: {}", text(o));
        assert!(stderr(o).contains(&want), "second process {i}: {}", text(o));
    }
    assert!(planted.exists(), "a refused process deleted a temp file");
    assert!(
        lock_text.contains(&format!("pid {pid}\nhost {host}\n")),
        "{lock_text:?}"
    );
    // SIGHUP: the frame is finished, checkpointed, and the run exits 130 with the resume command.
    let err = stderr(&first);
    assert_eq!(first.status.code(), Some(130), "{err}");
    assert!(err.contains("nimbus resume"), "{err}");
    assert!(std::fs::read_dir(out.join("checkpoints")).unwrap().count() > 0);

    // Two resumes at once: one wins, the other is refused; the winner cleans the stale temp.
    let a = resume(&out).stderr(Stdio::piped()).spawn().unwrap();
    let b = resume(&out).stderr(Stdio::piped()).spawn().unwrap();
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let codes = [a.status.code(), b.status.code()];
    assert!(
        codes == [Some(0), Some(2)] || codes == [Some(2), Some(0)],
        "{}\n{}",
        text(&a),
        text(&b)
    );
    let loser = if codes[0] == Some(2) { &a } else { &b };
    assert!(stderr(loser).contains("in use by pid"), "{}", text(loser));
    assert!(!planted.exists(), "the stale temp file was not cleaned");
    assert!(manifest(&out)["complete"].as_bool().unwrap());

    let reference = dir.path().join("ref");
    let o = run_tiny(&reference, &long);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(checksums(&out), checksums(&reference));
    // The lock file is empty once nobody holds it.
    assert_eq!(std::fs::read_to_string(out.join(".lock")).unwrap(), "");
}

#[test]
fn a_stale_lock_of_another_host_is_reported_not_broken() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(
        out.join(".lock"),
        "pid 4242\nhost farm-node-17\ncommand run\n",
    )
    .unwrap();
    let o = run_tiny(&out, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let err = stderr(&o);
    assert!(
        err.contains("in use by pid 4242 (host farm-node-17)"),
        "{err}"
    );
    assert!(!out.join("manifest.json").exists());
    // A dead pid of this host: reported and taken over.
    let host = nimbus::pipeline::lock::host_name();
    std::fs::write(out.join(".lock"), format!("pid 999999999\nhost {host}\n")).unwrap();
    let o = run_tiny(&out, &["--set", "output.frames.end=1"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        stderr(&o).contains("stale lock of pid 999999999"),
        "{}",
        text(&o)
    );
}
