//! Issue 13 cases 4, 6 and 7 through the real binary: whatever `run` would refuse, `validate`
//! refuses first (exit 2, FILE: --set KEY: reason) and a refused `run` leaves nothing behind;
//! frame ranges cannot wrap; a resume cannot contradict its own range; docs/CONFIG.md lists
//! every number key's range as validate checks it.
mod common;
use common::*;
use std::path::Path;

fn validate(sets: &[&str]) -> std::process::Output {
    let mut c = nimbus();
    c.arg("validate").arg(sample("tiny.yaml"));
    for s in sets {
        c.args(["--set", s]);
    }
    c.output().unwrap()
}

/// validate and run both exit 2 naming `key`; the refused run creates no directory.
fn refused(sets: &[&str], key: &str) {
    let o = validate(sets);
    assert_eq!(o.status.code(), Some(2), "{sets:?}: {}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("tiny.yaml: --set "), "{err}");
    assert!(err.contains(key), "{sets:?}: {err}");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut args: Vec<&str> = Vec::new();
    for s in sets {
        args.extend(["--set", s]);
    }
    let o = run_tiny(&out, &args);
    assert_eq!(o.status.code(), Some(2), "{sets:?}: {}", text(&o));
    assert!(!out.exists(), "a refused run left {}", out.display());
}

#[test]
fn what_run_refuses_validate_refuses_first() {
    let long = format!("shot={}", "s".repeat(300));
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["export.voxel_size=30"], "export.voxel_size"),
        (vec![long.as_str()], "shot"),
        (vec!["adaptive.min_distance=0.8"], "adaptive.min_distance"),
        (vec!["adaptive.split_offset=0.7"], "adaptive.split_offset"),
        (vec!["adaptive.split_offset=0"], "adaptive.split_offset"),
        (vec!["adaptive.max_level=8"], "adaptive.max_level"),
        (
            vec!["physics.ground_temperature=1e30"],
            "physics.ground_temperature",
        ),
        (vec!["export.voxel_size=1e30"], "export.voxel_size"),
        (vec!["output.frame_seconds=1e-50"], "output.frame_seconds"),
        (
            vec!["physics.heat_noise_contrast=-1"],
            "physics.heat_noise_contrast",
        ),
        (
            vec![
                "output.frames.start=4294967294",
                "output.frames.end=4294967295",
            ],
            "output.frames.",
        ),
        (vec!["output.frames.end=1000000000"], "output.frames.end"),
    ];
    for (sets, key) in cases {
        refused(&sets, key);
    }
    // The ends of a range are accepted.
    for s in [
        "adaptive.max_level=7",
        "adaptive.min_distance=0.6",
        "adaptive.split_offset=0.5",
    ] {
        let o = validate(&[s]);
        assert!(o.status.success(), "{s}: {}", text(&o));
    }
}

/// validate prints the particle count the run seeds (round(size/spacing) per axis, not floor).
#[test]
fn validate_prints_the_seeded_particle_count() {
    let sets = [
        "domain.size=[830,800,800]",
        "output.frames.end=1",
        "export.voxel_size=10",
    ];
    let o = validate(&sets);
    assert!(o.status.success(), "{}", text(&o));
    let line = String::from_utf8_lossy(&o.stdout).to_string();
    // 830 / 50 = 16.6 rounds to 17 (floor gave 16): 17 * 16 * 16.
    assert!(line.contains(" 4352 particles"), "{line}");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut args = Vec::new();
    for s in &sets {
        args.extend(["--set", *s]);
    }
    let o = run_tiny(&out, &args);
    assert!(o.status.success(), "{}", text(&o));
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    let first: serde_json::Value = serde_json::from_str(stats.lines().next().unwrap()).unwrap();
    assert_eq!(
        first["diagnostics"]["particles_level_0"].as_f64(),
        Some(4352.0),
        "{first}"
    );
}

/// Case 7: frames.end lowered in the manifest below the last checkpoint: the resume is refused
/// and changes nothing (it used to print "frames 15..=10" and mark the run complete).
#[test]
fn resume_past_a_lowered_end_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = run_tiny(&out, &[]);
    assert!(o.status.success(), "{}", text(&o));
    let mut m = manifest(&out);
    m["config"]["output"]["frames"]["end"] = 5.into();
    m["frame_end"] = 5.into();
    m["complete"] = false.into();
    let edited = serde_json::to_string_pretty(&m).unwrap();
    std::fs::write(out.join("manifest.json"), &edited).unwrap();
    let o = nimbus()
        .arg("resume")
        .arg(&out)
        .args(["--log-format", "json"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("frame 8") && err.contains("output.frames.end = 5"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("manifest.json")).unwrap(),
        edited
    );
    assert_eq!(count(&out.join("vdb")), 8);
}

fn count(dir: &Path) -> usize {
    std::fs::read_dir(dir).unwrap().count()
}

/// docs/CONFIG.md gives each number key the range validate checks.
#[test]
fn config_docs_list_every_range() {
    let doc = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/CONFIG.md"))
        .unwrap();
    for r in nimbus::config::FLOAT_RANGES {
        let row = doc
            .lines()
            .find(|l| l.starts_with(&format!("| `{}` |", r.key)) && l.split(" | ").count() >= 6)
            .unwrap_or_else(|| panic!("docs/CONFIG.md has no row for {}", r.key));
        let range_col = row.split(" | ").nth(4).unwrap_or("");
        assert!(
            range_col.contains(&r.text()),
            "{}: docs say {range_col:?}, validate checks {}",
            r.key,
            r.text()
        );
    }
    let max_level = format!("[0, {}]", nimbus::config::MAX_LEVEL);
    assert!(doc.contains(&format!(
        "| `adaptive.max_level` | u32 | - | 3 | {max_level}"
    )));
}
