//! `nimbus run` end to end on the real GPU path (lavapipe here): run records, files, determinism.
mod common;
use common::*;
use std::path::Path;

#[test]
fn run_writes_frames_manifest_and_stats() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = run_tiny(&out, &[]);
    assert!(o.status.success(), "{}", text(&o));
    for d in ["vdb", "exr", "preview", "checkpoints"] {
        assert!(out.join(d).is_dir(), "missing {d}/");
    }
    let m = manifest(&out);
    assert_eq!(m["complete"], true);
    assert!(m["adapter"].as_str().unwrap().len() > 3);
    assert_eq!(m["config_hash"].as_str().unwrap().len(), 64);
    let frames = m["frames"].as_array().unwrap();
    let (start, end) = (
        m["frame_start"].as_u64().unwrap(),
        m["frame_end"].as_u64().unwrap(),
    );
    assert_eq!(frames.len() as u64, end - start + 1);
    for (path, f) in checksums(&out).iter().map(|(_, p, s)| (out.join(p), s)) {
        let bytes = std::fs::read(&path)
            .unwrap_or_else(|_| panic!("{} listed but missing", path.display()));
        assert_eq!(
            &nimbus::pipeline::records::sha256_hex(&bytes),
            f,
            "{}",
            path.display()
        );
    }
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = stats
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len() as u64, end - start + 1);
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(l["frame"].as_u64().unwrap(), start + i as u64);
        assert!(l["particles"].as_u64().unwrap() > 0);
        assert!(l["sim_time"].as_f64().unwrap() > 0.0);
        assert!(l["phase_ms"].as_object().unwrap().len() >= 2, "{l}");
        for key in [
            "density_error_mean",
            "density_error_max",
            "total_water",
            "cloud_mass",
        ] {
            assert!(l["diagnostics"][key].is_number(), "stats lack {key}: {l}");
        }
    }
    // No temporary file is ever left behind.
    let leftovers: Vec<_> = walk(&out)
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".nimbus-tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn two_runs_give_identical_files_and_stats() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for out in [&a, &b] {
        let o = run_tiny(out, &[]);
        assert!(o.status.success(), "{}", text(&o));
    }
    assert_eq!(checksums(&a), checksums(&b));
    assert_eq!(stats_without_timings(&a), stats_without_timings(&b));
}

fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            v.extend(walk(&p));
        } else {
            v.push(p);
        }
    }
    v
}

#[test]
fn preview_command_reproduces_the_run_previews() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // supersaturated from the start: a cloud in every frame, so the light shows (the preview
    // has no ground, and an empty sky is one colour whatever the sun)
    let o = run_tiny(&out, &["--set", "physics.initial_vapor=1.1"]);
    assert!(o.status.success(), "{}", text(&o));
    let previews: Vec<(u64, String, String)> = checksums(&out)
        .into_iter()
        .filter(|(_, p, _)| p.starts_with("preview/"))
        .collect();
    assert_eq!(previews.len(), 8, "one preview per frame");
    let sheet = std::fs::read(out.join("preview/contact_sheet.png")).unwrap();
    for (_, p, _) in &previews {
        std::fs::remove_file(out.join(p)).unwrap();
    }
    let o = nimbus().arg("preview").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    for (_, p, sum) in &previews {
        let bytes = std::fs::read(out.join(p)).unwrap();
        assert_eq!(
            &nimbus::pipeline::records::sha256_hex(&bytes),
            sum,
            "{p} differs"
        );
    }
    assert_eq!(
        std::fs::read(out.join("preview/contact_sheet.png")).unwrap(),
        sheet
    );
    // A light override changes the pictures.
    let o = nimbus()
        .arg("preview")
        .arg(&out)
        .args(["--set", "output.preview.sun_direction=[-1,0.2,0]"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let (_, last, sum) = previews.last().unwrap();
    let bytes = std::fs::read(out.join(last)).unwrap();
    assert_ne!(&nimbus::pipeline::records::sha256_hex(&bytes), sum);
}

#[test]
fn no_gpu_adapter_is_exit_4_with_a_remedy() {
    let dir = tempfile::tempdir().unwrap();
    let o = run_tiny(
        &dir.path().join("run"),
        &["--set", "gpu.adapter=no-such-gpu-xyz"],
    );
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("mesa-vulkan-drivers"), "{err}");
}

/// A node without a Vulkan driver falls back to OpenGL and says so, with the remedy: on a CPU
/// that path ran the PBF step about 4x slower (docs/PERFORMANCE.md "PBF / Session 19"). With
/// Vulkan there, no warning.
#[test]
fn an_opengl_fallback_warns_with_the_remedy() {
    let bench = [
        "bench",
        "pbf",
        "--particles",
        "1000",
        "--steps",
        "1",
        "--warmup",
        "1",
    ];
    // the Vulkan loader finds no driver when its driver list names a file that does not exist
    let no_icd = "/nonexistent/nimbus-test-no-icd.json";
    let o = nimbus()
        .args(bench)
        .env("VK_ICD_FILENAMES", no_icd)
        .env("VK_DRIVER_FILES", no_icd)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(out.contains("(Gl)\""), "{out}");
    assert!(err.contains("no Vulkan adapter found"), "{err}");
    assert!(err.contains("mesa-vulkan-drivers"), "{err}");

    let o = nimbus().args(bench).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("(Vulkan)\""));
    assert!(!String::from_utf8_lossy(&o.stderr).contains("no Vulkan adapter"));
}

/// What is wrong with `--out` is said (exit 2) before the device is opened: on a machine without
/// a GPU too, where opening the device ends the run with exit 4. Nothing is written.
#[test]
fn a_bad_out_is_invalid_input_even_without_a_gpu() {
    let dir = tempfile::tempdir().unwrap();
    let no_icd = "/nonexistent/nimbus-test-no-icd.json";
    let run = |out: &Path| {
        nimbus()
            .arg("run")
            .arg(sample("tiny.yaml"))
            .arg("--out")
            .arg(out)
            .args(["--set", "gpu.backend=vulkan"])
            .env("VK_ICD_FILENAMES", no_icd)
            .env("VK_DRIVER_FILES", no_icd)
            .output()
            .unwrap()
    };
    // no device at all: a good --out gets exit 4, and nothing is made
    let fresh = dir.path().join("fresh");
    let o = run(&fresh);
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    assert!(!fresh.exists());
    // a file as --out
    let file = dir.path().join("a_file");
    std::fs::write(&file, b"x").unwrap();
    let o = run(&file);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("is a file, not a run directory"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
    // a directory holding files nimbus did not write
    let foreign = dir.path().join("foreign");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), b"mine").unwrap();
    let o = run(&foreign);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("nimbus did not write"), "{}", text(&o));
    let names: Vec<_> = std::fs::read_dir(&foreign)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["notes.txt"]);
}
