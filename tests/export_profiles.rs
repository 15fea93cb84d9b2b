//! Renderer profiles, scale and up axis as the files show them: real OpenVDB (pyopenvdb under
//! /usr/bin/python3) reads a `--set export.profile=houdini` run with the names, classes and
//! metadata Houdini expects; and a RenderMan run at another scale and axis holds the same cloud,
//! voxel for voxel, at the rotated and scaled positions, with velocities per frame.
mod common;
use common::*;
use nimbus::io::vdb::{read_file, GridData, MetaValue};
use std::path::{Path, PathBuf};
use std::process::Command;

fn run(name: &str, sets: &[&str]) -> PathBuf {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&out);
    let mut extra = vec![
        "--set",
        "output.frames.end=3",
        "--set",
        "output.preview.enabled=false",
    ];
    for s in sets {
        extra.push("--set");
        extra.push(s);
    }
    let o = run_tiny(&out, &extra);
    assert!(o.status.success(), "{}", text(&o));
    out
}

const PY: &str = r#"
import sys, json, pyopenvdb as vdb
grids, meta = vdb.readAll(sys.argv[1])
def plain(v):
    return v if isinstance(v, (int, float, str, bool)) else list(v)
out = {"meta": {k: plain(v) for k, v in meta.items()}, "grids": {}}
for g in grids:
    out["grids"][g.name] = {"type": g.valueTypeName, "class": g.gridClass,
        "voxel": list(g.transform.voxelSize()), "active": g.activeVoxelCount(),
        "meta": {k: plain(v) for k, v in g.metadata.items()}}
print(json.dumps(out))
"#;

#[test]
fn houdini_profile_reads_right_in_openvdb() {
    if !common::pyopenvdb_available() {
        eprintln!("note: /usr/bin/python3 has no pyopenvdb; OpenVDB check skipped");
        return;
    }
    let out = run("profile_houdini", &["export.profile=houdini"]);
    let o = Command::new("/usr/bin/python3")
        .arg("-c")
        .arg(PY)
        .arg(out.join("vdb/tiny.0003.vdb"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &j["grids"];
    let mut names: Vec<_> = g.as_object().unwrap().keys().cloned().collect();
    names.sort();
    assert_eq!(names, ["density", "temperature", "vapor", "vel"], "{j}");
    for n in ["density", "temperature", "vapor"] {
        assert_eq!(g[n]["type"], "float", "{n}");
        assert_eq!(g[n]["class"], "fog volume", "{n}");
        assert_eq!(g[n]["voxel"], serde_json::json!([25.0, 25.0, 25.0]), "{n}");
    }
    let vel = &g["vel"];
    assert_eq!(vel["type"], "vec3s");
    assert_eq!(vel["class"], "unknown");
    assert_eq!(vel["meta"]["vector_type"], "contravariant relative");
    assert_eq!(vel["meta"]["nimbus_velocity_time"], "playback");
    assert_eq!(
        vel["meta"]["nimbus_velocity_unit"],
        "scene units per second of playback"
    );
    assert_eq!(vel["meta"]["nimbus_fps"], 24.0);
    assert_eq!(vel["meta"]["nimbus_frame_seconds"], 5.0);
    assert!(vel["active"].as_u64().unwrap() > 0);
    let m = &j["meta"];
    assert_eq!(m["nimbus_profile"], "houdini");
    assert_eq!(m["nimbus_up_axis"], "y");
    assert_eq!(m["nimbus_metres_per_unit"], 1.0);
    assert_eq!(m["nimbus_voxel_size"], 25.0);
    let man = manifest(&out);
    assert_eq!(man["export"]["profile"], "houdini");
    assert_eq!(man["export"]["velocity_time"], "playback");
}

/// (index, value) of every active voxel.
fn active<T: Copy>(g: &nimbus::ground::SparseGrid<T>) -> Vec<([i32; 3], T)> {
    let mut v = Vec::new();
    for l in &g.leaves {
        for n in 0..512 {
            if l.is_active(n) {
                let local = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
                v.push(([0, 1, 2].map(|k| l.origin[k] + local[k]), l.values[n]));
            }
        }
    }
    v
}

#[test]
fn renderman_at_another_scale_and_axis_holds_the_same_cloud() {
    let plain = run("profile_plain", &[]);
    let rman = run(
        "profile_renderman",
        &[
            "export.profile=renderman",
            "export.scale=10",
            "export.up_axis=z",
        ],
    );
    let a = read_file(&plain.join("vdb/tiny.0003.vdb")).unwrap();
    let b = read_file(&rman.join("vdb/tiny.0003.vdb")).unwrap();
    let vel_b = b.grid("vel").unwrap();
    assert_eq!(
        vel_b.meta("class"),
        Some(&MetaValue::String("fog volume".into()))
    );
    assert_eq!(
        vel_b.meta("nimbus_velocity_time"),
        Some(&MetaValue::String("per_frame".into()))
    );
    // nimbus (x, y, z) metres is (x, -z, y) / 10 in the export
    let map = |p: [f64; 3]| [p[0] / 10.0, -p[2] / 10.0, p[1] / 10.0];
    // (tiny's cloud forms later than frame 3: density may be empty, vapor and temperature not)
    for name in ["density", "temperature", "vapor"] {
        let (Some(GridData::Float(ga)), Some(GridData::Float(gb))) =
            (a.grid(name).map(|g| &g.data), b.grid(name).map(|g| &g.data))
        else {
            panic!("no float grid {name}")
        };
        assert!((gb.transform.voxel_size - 2.5).abs() < 1e-12);
        let va = active(ga);
        assert!(name == "density" || !va.is_empty(), "{name} is empty");
        assert_eq!(va.len() as u64, gb.active_voxel_count(), "{name}");
        for (ijk, x) in va {
            let p = ga.transform.index_to_world(ijk.map(|i| i as f64));
            let q = gb.transform.world_to_index(map(p));
            let qi = q.map(|c| c.round() as i32);
            assert!(q.iter().all(|c| (c - c.round()).abs() < 1e-6), "{q:?}");
            assert_eq!(gb.get(qi), x, "{name} at {ijk:?}");
        }
    }
    let (Some(GridData::Vec3(ga)), GridData::Vec3(gb)) =
        (a.grid("vel").map(|g| &g.data), &vel_b.data)
    else {
        panic!("no vel grids")
    };
    // playback: v x 5 s x 24 fps; per frame at scale 10: v x 5 s / 10
    let k = (5.0 / 10.0) / (5.0 * 24.0);
    for (ijk, u) in active(ga) {
        let p = ga.transform.index_to_world(ijk.map(|i| i as f64));
        let q = gb
            .transform
            .world_to_index(map(p))
            .map(|c| c.round() as i32);
        let w = gb.get(q);
        let want = [u[0] as f64 * k, -u[2] as f64 * k, u[1] as f64 * k];
        for c in 0..3 {
            assert!(
                (w[c] as f64 - want[c]).abs() <= 1e-5 * (1.0 + want[c].abs()),
                "vel at {ijk:?}: {w:?} vs {want:?}"
            );
        }
    }
}

/// `nimbus preview` renders from the VDB files: it maps a z-up, scaled export back into nimbus's
/// frame, so its images are the run's own, byte for byte.
#[test]
fn preview_of_a_blender_export_matches_the_run() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("profile_blender_preview");
    let _ = std::fs::remove_dir_all(&out);
    let o = run_tiny(
        &out,
        &[
            "--set",
            "export.profile=blender",
            "--set",
            "export.scale=100",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let png = out.join("preview/tiny.0008.png");
    let before = std::fs::read(&png).unwrap();
    let o = nimbus().arg("preview").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(std::fs::read(&png).unwrap(), before);
}
