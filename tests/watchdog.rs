//! The divergence watchdog through the real binary (issue 13 case 5): a state that turns NaN
//! stops the run with exit 3 naming the frame, field and particle; nothing of that frame is
//! written, the manifest stays incomplete, the last good checkpoint is kept and resumes.
mod common;
use common::*;

#[test]
fn a_nan_state_exits_3_and_keeps_the_last_good_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("ref");
    let o = run_tiny(&reference, &[]);
    assert!(o.status.success(), "{}", text(&o));

    let out = dir.path().join("run");
    let o = nimbus()
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&out)
        .args(["--log-format", "json"])
        .env("NIMBUS_FAULT", "nan:5")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("simulation diverged at frame 5: temperature = NaN at particle 0"),
        "{err}"
    );
    let m = manifest(&out);
    assert_eq!(m["complete"], false);
    let frames: Vec<u64> = m["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["frame"].as_u64().unwrap())
        .collect();
    assert_eq!(frames, [1, 2, 3, 4]);
    assert!(!out.join("vdb/tiny.0005.vdb").exists());
    assert!(out.join("checkpoints/ckpt_000004.nck").exists());
    assert!(!out.join("checkpoints/ckpt_000005.nck").exists());

    let o = nimbus()
        .arg("resume")
        .arg(&out)
        .args(["--log-format", "json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(checksums(&out), checksums(&reference));
}

/// `output.frame_seconds: 1e-50` used to run to NaN with exit 0; validate now refuses it.
#[test]
fn time_steps_that_underflow_f32_are_refused_by_validate() {
    for v in ["1e-50", "1e-30", "1e30"] {
        let o = nimbus()
            .arg("validate")
            .arg(sample("tiny.yaml"))
            .args(["--set", &format!("output.frame_seconds={v}")])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{v}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--set output.frame_seconds:"), "{err}");
    }
}
