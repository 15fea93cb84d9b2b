//! `nimbus export RUN_DIR [--frames A-B] [--set export.key=value]...` re-makes a run's files from
//! its particle caches: byte-identical with the run's own settings; with others, in
//! `exports/<name>/` with its own manifest, filled by several invocations (farm jobs) in turn.
mod common;
use common::*;
use nimbus::io::vdb::{read_file, GridData};
use nimbus::pipeline::records::sha256_hex;
use std::path::{Path, PathBuf};

fn fresh(name: &str) -> PathBuf {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&out);
    out
}

fn export(run: &Path, args: &[&str]) -> std::process::Output {
    nimbus()
        .arg("export")
        .arg(run)
        .args(args)
        .output()
        .expect("nimbus runs")
}

/// Every file the manifest of `dir` lists has its recorded SHA-256 on disk.
fn all_as_recorded(dir: &Path) {
    for (frame, path, sha) in checksums(dir) {
        let bytes = std::fs::read(dir.join(&path)).unwrap_or_else(|e| panic!("{path}: {e}"));
        assert_eq!(sha256_hex(&bytes), sha, "frame {frame}: {path}");
    }
}

/// Integral of a float grid (sum of values x voxel volume).
fn integral(path: &Path, grid: &str) -> (f64, f64) {
    let f = read_file(path).unwrap();
    let Some(GridData::Float(g)) = f.grid(grid).map(|g| &g.data) else {
        panic!("{}: no {grid}", path.display())
    };
    let mut s = 0.0;
    for l in &g.leaves {
        for n in 0..512 {
            if l.is_active(n) {
                s += l.values[n] as f64;
            }
        }
    }
    let v = g.transform.voxel_size;
    (s * v * v * v, v)
}

#[test]
fn export_remakes_a_run_and_writes_other_settings_apart() {
    let run = fresh("export_cmd");
    let o = run_tiny(
        &run,
        &[
            "--set",
            "output.frames.end=4",
            "--set",
            "export.particles=true",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let manifest_before = std::fs::read(run.join("manifest.json")).unwrap();
    let recorded = checksums(&run);
    assert!(recorded
        .iter()
        .any(|(_, p, _)| p == "particles/tiny.0002.ply"));

    // Own settings: the lost files of frames 2 and 3 come back byte for byte.
    for f in [
        "vdb/tiny.0002.vdb",
        "exr/tiny.0003.exr",
        "preview/tiny.0003.png",
    ] {
        std::fs::remove_file(run.join(f)).unwrap();
    }
    let o = export(&run, &["--frames", "2-3"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("2 frames written"),
        "{}",
        text(&o)
    );
    all_as_recorded(&run);
    assert_eq!(
        std::fs::read(run.join("manifest.json")).unwrap(),
        manifest_before
    );
    // Nothing lost: nothing to do.
    let o = export(&run, &[]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("0 frames written, 4 already as recorded"),
        "{}",
        text(&o)
    );

    // Other settings, 4x finer, in two invocations like two farm jobs.
    let sets = [
        "--set",
        "export.voxel_size=6.25",
        "--set",
        "export.profile=houdini",
        "--name",
        "fine",
    ];
    let o = export(&run, &[&["--frames", "3-4"][..], &sets[..]].concat());
    assert!(o.status.success(), "{}", text(&o));
    let dir = run.join("exports/fine");
    let m = manifest(&dir);
    assert_eq!(m["complete"], false);
    assert_eq!(m["frames"].as_array().unwrap().len(), 2);
    let o = export(&run, &[&["--frames", "1-2"][..], &sets[..]].concat());
    assert!(o.status.success(), "{}", text(&o));
    let m = manifest(&dir);
    assert_eq!(m["complete"], true, "{m}");
    assert_eq!(m["frames"].as_array().unwrap().len(), 4);
    assert_eq!(m["voxel_size"], 6.25);
    assert_eq!(m["export"]["profile"], "houdini");
    all_as_recorded(&dir);
    // the same vapor, at a quarter of the voxel size
    for f in 1..=4 {
        let (coarse, vc) = integral(&run.join(format!("vdb/tiny.{f:04}.vdb")), "vapor");
        let (fine, vf) = integral(&dir.join(format!("vdb/tiny.{f:04}.vdb")), "vapor");
        assert_eq!((vc, vf), (25.0, 6.25));
        assert!(
            (fine / coarse - 1.0).abs() < 0.02,
            "frame {f}: vapor integral {fine} vs {coarse}"
        );
    }
    // the run's own files are untouched by the other export
    all_as_recorded(&run);
    assert_eq!(checksums(&run), recorded);

    // An export directory is nimbus's own: a forced fresh run over it is not refused.
    let o = run_tiny(&run, &["--set", "output.frames.end=1", "--force"]);
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn export_refuses_what_it_cannot_do() {
    let run = fresh("export_cmd_refusals");
    let o = run_tiny(
        &run,
        &[
            "--set",
            "output.frames.end=2",
            "--set",
            "export.particles=true",
            "--set",
            "output.preview.enabled=false",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    for (args, needle) in [
        (vec!["--set", "domain.spacing=10"], "export.* keys only"),
        (
            vec!["--set", "export.particles=false"],
            "export.* keys only",
        ),
        (vec!["--frames", "2-5"], "frames 3-5 are not in the run"),
        (vec!["--frames", "x"], "expected A-B"),
        (vec!["--set", "export.scale=0"], "export.scale"),
        (
            vec!["--set", "export.voxel_size=50", "--name", "../up"],
            "--name",
        ),
    ] {
        let o = export(&run, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
    }
    // a damaged cache is refused, naming it
    let ply = run.join("particles/tiny.0002.ply");
    let mut b = std::fs::read(&ply).unwrap();
    let last = b.len() - 1;
    b[last] ^= 1;
    std::fs::write(&ply, b).unwrap();
    let o = export(&run, &["--set", "export.voxel_size=50"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("particles/tiny.0002.ply"));

    // a run without caches has nothing to export from
    let plain = fresh("export_cmd_plain");
    let o = run_tiny(&plain, &["--set", "output.frames.end=1"]);
    assert!(o.status.success(), "{}", text(&o));
    let o = export(&plain, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("export.particles"));
}
