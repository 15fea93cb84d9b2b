//! `export.detail` and the rest grids through the real binary: a run that tracks rest positions
//! resumes bit for bit, `nimbus export` re-makes it byte for byte, and writes a 4x finer, detailed
//! export of the same run in its own directory with the undetailed mass.
mod common;
use common::*;
use nimbus::ground::SparseGrid;
use nimbus::io::vdb::{read_file, GridData, MetaValue};
use nimbus::pipeline::records::sha256_hex;
use std::path::{Path, PathBuf};

/// tiny, cloudy from the first frame (supersaturated), with detail that shows at its own 25 m
/// voxels (a 60 m first octave) and both rest grids, resetting every 2 frames.
const SETS: [&str; 14] = [
    "--set",
    "physics.initial_vapor=1.01",
    "--set",
    "export.particles=true",
    "--set",
    "export.detail.enabled=true",
    "--set",
    "export.detail.scale=60",
    "--set",
    "export.detail.rest_period=2",
    "--set",
    "export.grids.rest=rest",
    "--set",
    "output.frames.end=3",
];

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

fn all_as_recorded(dir: &Path) {
    for (frame, path, sha) in checksums(dir) {
        let bytes = std::fs::read(dir.join(&path)).unwrap_or_else(|e| panic!("{path}: {e}"));
        assert_eq!(sha256_hex(&bytes), sha, "frame {frame}: {path}");
    }
}

fn density(path: &Path) -> SparseGrid<f32> {
    let f = read_file(path).unwrap();
    match f.grid("density").map(|g| &g.data) {
        Some(GridData::Float(g)) => g.clone(),
        _ => panic!("{}: no density", path.display()),
    }
}

/// Sum of the active values x voxel volume.
fn integral(g: &SparseGrid<f32>) -> f64 {
    let v = g.transform.voxel_size;
    let s: f64 = g
        .leaves
        .iter()
        .flat_map(|l| {
            (0..512)
                .filter(|&n| l.is_active(n))
                .map(|n| l.values[n] as f64)
        })
        .sum();
    s * v * v * v
}

#[test]
fn a_run_with_rest_positions_resumes_bit_for_bit() {
    let whole = fresh("detail_whole");
    let o = run_tiny(&whole, &SETS);
    assert!(o.status.success(), "{}", text(&o));
    // killed while simulating frame 3: resumes from the checkpoint of frame 2
    let cut = fresh("detail_cut");
    let o = nimbus()
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&cut)
        .args(SETS)
        .env("NIMBUS_FAULT", "frame:3")
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    let o = nimbus().arg("resume").arg(&cut).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(checksums(&cut), checksums(&whole));
    assert!(checksums(&whole)
        .iter()
        .any(|(_, p, _)| p == "particles/tiny.0003.ply"));
}

#[test]
fn export_remakes_a_detailed_run_and_writes_a_4x_finer_detailed_export() {
    let run = fresh("detail_export");
    let o = run_tiny(&run, &SETS);
    assert!(o.status.success(), "{}", text(&o));
    let recorded = checksums(&run);
    // the caches carry the rest positions
    let ply = std::fs::read(run.join("particles/tiny.0002.ply")).unwrap();
    let head = String::from_utf8_lossy(&ply[..2000.min(ply.len())]).to_string();
    assert!(
        head.contains("property float rest2_z\nend_header"),
        "{head}"
    );

    // Own settings: lost files come back byte for byte.
    for f in [
        "vdb/tiny.0002.vdb",
        "preview/tiny.0002.png",
        "exr/tiny.0002.exr",
    ] {
        std::fs::remove_file(run.join(f)).unwrap();
    }
    let o = export(&run, &["--frames", "2-2"]);
    assert!(o.status.success(), "{}", text(&o));
    all_as_recorded(&run);
    assert_eq!(checksums(&run), recorded);

    // 4x finer, detailed, in its own directory; and the same without detail to compare.
    let fine = ["--frames", "1-2", "--set", "export.voxel_size=6.25"];
    let o = export(&run, &[&fine[..], &["--name", "fine"]].concat());
    assert!(o.status.success(), "{}", text(&o));
    let o = export(
        &run,
        &[
            &fine[..],
            &["--set", "export.detail.enabled=false", "--name", "plain"],
        ]
        .concat(),
    );
    assert!(o.status.success(), "{}", text(&o));
    let dir = run.join("exports/fine");
    all_as_recorded(&dir);
    assert_eq!(manifest(&dir)["voxel_size"], 6.25);
    for f in 1..=2 {
        let name = format!("vdb/tiny.{f:04}.vdb");
        let coarse = density(&run.join(&name));
        let detailed = density(&dir.join(&name));
        let plain = density(&run.join("exports/plain").join(&name));
        assert_eq!(detailed.transform.voxel_size, 6.25);
        let (c, d, p) = (integral(&coarse), integral(&detailed), integral(&plain));
        assert!(p > 0.0);
        assert!(
            (d / p - 1.0).abs() < 0.05,
            "frame {f}: detailed {d} vs undetailed {p}"
        );
        assert!(
            (d / c - 1.0).abs() < 0.05,
            "frame {f}: detailed {d} vs the run's {c}"
        );
        // the detail is there: voxels differ by a good fraction of their value
        let (mut diff, mut norm) = (0.0, 0.0);
        for l in &plain.leaves {
            for n in 0..512 {
                let ijk = [
                    l.origin[0] + (n >> 6) as i32,
                    l.origin[1] + ((n >> 3) & 7) as i32,
                    l.origin[2] + (n & 7) as i32,
                ];
                let (a, b) = (l.values[n] as f64, detailed.get(ijk) as f64);
                diff += (a - b) * (a - b);
                norm += a * a;
            }
        }
        assert!(
            (diff / norm).sqrt() > 0.1,
            "frame {f}: {}",
            (diff / norm).sqrt()
        );
        // both rest grids, with their blend weights summing to 1
        let file = read_file(&dir.join(&name)).unwrap();
        let mut w = 0.0;
        for g in ["rest", "rest2"] {
            let grid = file.grid(g).unwrap_or_else(|| panic!("no {g}"));
            assert!(matches!(&grid.data, GridData::Vec3(v) if v.transform.voxel_size == 6.25));
            match grid
                .metadata
                .iter()
                .find(|(k, _)| k == "nimbus_rest_weight")
            {
                Some((_, MetaValue::Double(x))) => w += x,
                m => panic!("{g}: {m:?}"),
            }
        }
        assert!((w - 1.0).abs() < 1e-12);
    }
    // the run's own files are untouched
    assert_eq!(checksums(&run), recorded);

    // What export cannot do: change the reset period, or add detail to caches without rest.
    let o = export(&run, &["--set", "export.detail.rest_period=5"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    let bare = fresh("detail_bare");
    let o = run_tiny(
        &bare,
        &[
            "--set",
            "output.frames.end=1",
            "--set",
            "export.particles=true",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let o = export(&bare, &["--set", "export.detail.enabled=true"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("rest positions"),
        "{}",
        text(&o)
    );
}
