//! `output.preroll`: frames simulated before the first written one. They are the same
//! simulation as the frames of a run without a pre-roll (the written frames are that run's
//! later frames), nothing of them is written, the manifest records them, and a run killed in
//! its pre-roll resumes there to the same bytes as an uninterrupted run.
mod common;
use common::*;
use std::path::Path;

/// tiny's frames are 5 s: 10 s of pre-roll are 2 frames, 7 s are rounded up to 2 as well.
const PREROLL: &[&str] = &["--set", "output.preroll=7", "--set", "output.frames.end=4"];

fn stats(out: &Path) -> Vec<serde_json::Value> {
    stats_without_timings(out)
}

#[test]
fn preroll_frames_are_simulated_and_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let (with, without) = (dir.path().join("with"), dir.path().join("without"));
    let o = run_tiny(&with, PREROLL);
    assert!(o.status.success(), "{}", text(&o));
    let o = run_tiny(&without, &["--set", "output.frames.end=6"]);
    assert!(o.status.success(), "{}", text(&o));

    // the manifest: the pre-roll's frames and seconds, and only frames 1-4
    let m = manifest(&with);
    assert_eq!(m["preroll"]["frames"], 2, "{}", m["preroll"]);
    assert_eq!(m["preroll"]["seconds"], 10.0);
    assert_eq!(m["preroll"]["first_frame_time"], 15.0);
    let frames: Vec<u64> = m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["frame"].as_u64().unwrap())
        .collect();
    assert_eq!(frames, [1, 2, 3, 4]);
    assert!(manifest(&without).get("preroll").is_none());
    // no file of a pre-roll frame: every VDB is one the manifest records
    let vdbs = std::fs::read_dir(with.join("vdb")).unwrap().count();
    assert_eq!(vdbs, 4);

    // frame f after the pre-roll is frame f + 2 of the run without one: the same particles, the
    // same diagnostics, simulated time counted from the start of the pre-roll
    let (a, b) = (stats(&with), stats(&without));
    assert_eq!(a.len(), 4);
    for (f, s) in a.iter().enumerate() {
        let mut t = b[f + 2].clone();
        t["frame"] = s["frame"].clone();
        assert_eq!(s, &t, "frame {} against frame {}", f + 1, f + 3);
    }
    assert_eq!(a[0]["sim_time"], 15.0);
}

#[test]
fn killed_in_the_preroll_resumes_to_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, cut) = (dir.path().join("whole"), dir.path().join("cut"));
    // a checkpoint every pre-roll frame: the first is kept, the process dies renaming the second
    let sets = [PREROLL, &["--set", "checkpoint.every=1"]].concat();
    let o = run_tiny(&whole, &sets);
    assert!(o.status.success(), "{}", text(&o));
    let o = {
        let mut c = nimbus();
        c.arg("run")
            .arg(sample("tiny.yaml"))
            .arg("--out")
            .arg(&cut)
            .args(["--log-format", "json"])
            .args(&sets)
            .env("NIMBUS_FAULT", "rename:ckpt_:2");
        c.output().unwrap()
    };
    assert!(
        !o.status.success(),
        "the fault did not stop the run: {}",
        text(&o)
    );
    assert!(
        !cut.join("vdb").exists() || std::fs::read_dir(cut.join("vdb")).unwrap().count() == 0,
        "a frame was written in the pre-roll"
    );
    let r = nimbus()
        .arg("resume")
        .arg(&cut)
        .args(["--log-format", "json"])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", text(&r));
    let log = String::from_utf8_lossy(&r.stderr).to_string() + &String::from_utf8_lossy(&r.stdout);
    assert!(log.contains("pre-roll: 1 of 2 frames"), "{log}");
    assert_eq!(checksums(&cut), checksums(&whole));
    assert_eq!(stats(&cut), stats(&whole));
}

#[test]
fn a_preroll_out_of_range_is_invalid_input() {
    for (set, key) in [
        ("output.preroll=-1", "output.preroll"),
        ("output.preroll=1e9", "output.preroll"),
    ] {
        let o = nimbus()
            .arg("validate")
            .arg(sample("tiny.yaml"))
            .args(["--set", set])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{set}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(key), "{set}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{set}: {err}");
    }
    // 5 s frames: 1e7 s would be 2M pre-roll frames, over the limit of 1M
    let o = nimbus()
        .arg("validate")
        .arg(sample("tiny.yaml"))
        .args(["--set", "output.preroll=1e7"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}
