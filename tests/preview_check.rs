//! `nimbus preview` checks every VDB against the manifest (issue 13 case 8), and path errors of
//! `inspect` are invalid input.
mod common;
use common::*;

#[test]
fn preview_reports_missing_and_swapped_frames_and_leaves_no_stale_png() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = run_tiny(&out, &[]);
    assert!(o.status.success(), "{}", text(&o));
    std::fs::remove_file(out.join("vdb/tiny.0003.vdb")).unwrap();
    std::fs::copy(out.join("vdb/tiny.0006.vdb"), out.join("vdb/tiny.0005.vdb")).unwrap();
    let o = nimbus().arg("preview").arg(&out).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("frame 3: vdb/tiny.0003.vdb: missing"), "{err}");
    assert!(
        err.contains("frame 5: vdb/tiny.0005.vdb: SHA-256 differs"),
        "{err}"
    );
    assert!(
        err.contains("2 of 8 frames could not be previewed"),
        "{err}"
    );
    for f in [3, 5] {
        assert!(
            !out.join(format!("preview/tiny.000{f}.png")).exists(),
            "stale png {f}"
        );
    }
    for f in [1, 2, 4, 6, 7, 8] {
        assert!(
            out.join(format!("preview/tiny.000{f}.png")).exists(),
            "png {f}"
        );
    }
}

#[test]
fn inspect_of_a_directory_or_device_is_invalid_input() {
    let dir = tempfile::tempdir().unwrap();
    for p in [
        dir.path().to_str().unwrap(),
        "/dev/zero",
        "/no/such/file.vdb",
    ] {
        let t0 = std::time::Instant::now();
        let o = nimbus().arg("inspect").arg(p).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{p}: {}", text(&o));
        assert!(t0.elapsed().as_secs_f64() < 1.0);
    }
}
