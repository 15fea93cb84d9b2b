//! `export.usd`: the layer `<shot>.usda` read by USD itself (PyPI usd-core's `pxr`, in the venv
//! tools/setup.sh makes) and its VDB files by pyopenvdb (tests/data/check_usd_layer.py): the
//! stage opens and passes USD's compliance checker, every `filePath` sample resolves to the
//! frame's VDB file, which holds the field's grid, and the stage metadata is the manifest's.
//! From `run`, an extended (resumed) run, `nimbus export` into `exports/<name>/`, and after the
//! run directory moved. Also the refusals of `export.usd` and `export.nanovdb` settings.
mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

fn fresh(name: &str) -> PathBuf {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&out);
    out
}

/// Where tools/setup.sh installs USD's Python module (`NIMBUS_USD_VENV` there).
const USD_VENV: &str = "/opt/nimbus/usd";

/// A python3 that imports both `pxr` and `pyopenvdb`: NIMBUS_USD_PYTHON, else the venv's. Under
/// CI=true (where .ci/run installs it) a missing one fails the test instead of skipping it.
fn usd_python() -> Option<PathBuf> {
    let python = std::env::var_os("NIMBUS_USD_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(USD_VENV).join("bin/python"));
    let ok = Command::new(&python)
        .args(["-c", "import pxr.Usd, pyopenvdb"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok && std::env::var("CI").as_deref() == Ok("true") {
        panic!(
            "CI=true but {} cannot import pxr and pyopenvdb: CI must install them (tools/setup.sh)",
            python.display()
        );
    }
    ok.then_some(python)
}

/// The layer of `dir` checked against `dir`'s manifest; returns the script's summary.
fn check_layer(python: &Path, dir: &Path, shot: &str) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/check_usd_layer.py");
    let o = Command::new(python)
        .arg(script)
        .arg(dir.join(format!("{shot}.usda")))
        .arg(dir.join("manifest.json"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}: {}", dir.display(), text(&o));
    let line = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(line.trim()).unwrap()
}

/// The manifest records the layer with its size and SHA-256.
fn recorded(dir: &Path) -> String {
    let m = manifest(dir);
    let rec = &m["usd"];
    let bytes = std::fs::read(dir.join(rec["path"].as_str().unwrap())).unwrap();
    assert_eq!(rec["bytes"], bytes.len() as u64, "{rec}");
    assert_eq!(
        rec["sha256"],
        nimbus::pipeline::records::sha256_hex(&bytes).as_str()
    );
    String::from_utf8(bytes).unwrap()
}

const SETS: [&str; 10] = [
    "--set",
    "export.usd=true",
    "--set",
    "export.particles=true",
    // z-up, a `heat` alias of the temperature, 100 m per scene unit
    "--set",
    "export.profile=blender",
    "--set",
    "export.scale=100",
    "--set",
    "physics.initial_vapor=1.01",
];

#[test]
fn usd_layer_opens_and_points_at_every_frame() {
    let Some(python) = usd_python() else {
        eprintln!("note: USD's Python module is not installed (tools/setup.sh); skipping");
        return;
    };
    let base = fresh("usd_layer");
    let run = base.join("run");
    let mut args = SETS.to_vec();
    args.extend(["--set", "output.frames.end=3"]);
    let o = run_tiny(&run, &args);
    assert!(o.status.success(), "{}", text(&o));
    let s = check_layer(&python, &run, "tiny");
    assert_eq!(s["frames"], 3, "{s}");
    assert_eq!(
        s["fields"],
        serde_json::json!(["density", "heat", "temperature", "vapor", "vel"])
    );
    assert_eq!(s["stage"]["upAxis"], "Z");
    assert_eq!(s["stage"]["metersPerUnit"], 100.0);
    let three = recorded(&run);

    // Extended: the same run goes on to frame 5; the layer is rewritten with the new frames.
    let mut args = SETS.to_vec();
    args.extend(["--set", "output.frames.end=5", "--resume"]);
    let o = run_tiny(&run, &args);
    assert!(o.status.success(), "{}", text(&o));
    let s = check_layer(&python, &run, "tiny");
    assert_eq!(s["frames"], 5, "{s}");
    assert_eq!(s["stage"]["endTimeCode"], 5.0);
    let five = recorded(&run);
    assert!(five.len() > three.len());
    assert!(five.contains("5: @./vdb/tiny.0005.vdb@"), "{five}");

    // From the particle caches into an export directory: a layer of its own, over its files.
    let o = nimbus()
        .arg("export")
        .arg(&run)
        .args(["--frames", "2-4", "--set", "export.voxel_size=50"])
        .args(["--set", "export.profile=houdini", "--name", "coarse"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let coarse = run.join("exports/coarse");
    let s = check_layer(&python, &coarse, "tiny");
    assert_eq!(s["frames"], 3, "{s}");
    assert_eq!(s["stage"]["upAxis"], "Y");
    assert_eq!(s["stage"]["startTimeCode"], 2.0);
    recorded(&coarse);

    // The asset paths are relative: the run directory can move.
    let moved = base.join("moved");
    std::fs::rename(&run, &moved).unwrap();
    check_layer(&python, &moved, "tiny");
    check_layer(&python, &moved.join("exports/coarse"), "tiny");

    // The run's own settings: a lost layer is made again, as recorded.
    std::fs::remove_file(moved.join("tiny.usda")).unwrap();
    let o = nimbus()
        .arg("export")
        .arg(&moved)
        .args(["--frames", "1"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(recorded(&moved), five);
}

/// Writes `body` as a config in `dir` (the shot is tiny's) and returns its path.
fn config(dir: &Path, body: &str) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("handoff.yaml");
    std::fs::write(
        &p,
        format!(
            "shot: bad\noutput:\n  frames: {{start: 1, end: 2}}\ndomain:\n  size: [800, 800, 800]\n  spacing: 50\n{body}"
        ),
    )
    .unwrap();
    p
}

#[test]
fn bad_usd_and_nanovdb_settings_are_refused_at_their_line() {
    let base = fresh("handoff_refused");
    // (body after 6 lines of header, line, token, key, words)
    let cases: [(&str, usize, &str, &str, &str); 5] = [
        (
            "export:\n  usd: true\n  vdb:\n    enabled: false\n",
            2,
            "usd",
            "export.usd",
            "export.vdb.enabled is false",
        ),
        (
            "export:\n  nanovdb:\n    enabled: true\n    precision: fp8\n",
            4,
            "precision",
            "export.nanovdb.precision",
            "fp8 quantises float grids only, and \"vel\" is a vector grid",
        ),
        (
            "export:\n  nanovdb:\n    enabled: true\n    grids: {density: fp8, vel: fp16}\n",
            4,
            "vel",
            "export.nanovdb.grids.vel",
            "fp16 quantises float grids only",
        ),
        (
            "export:\n  nanovdb:\n    enabled: true\n    grids: [density, smoke]\n",
            4,
            "smoke",
            "export.nanovdb.grids[1]",
            "\"smoke\" is not a grid of the VDB files (they hold: density, temperature, vapor, vel)",
        ),
        (
            "export:\n  grids:\n    vapor: \"\"\n  nanovdb: {enabled: true, grids: [vapor]}\n",
            4,
            "vapor]",
            "export.nanovdb.grids[0]",
            "\"vapor\" is not a grid of the VDB files",
        ),
    ];
    for (i, (body, line, token, key, words)) in cases.iter().enumerate() {
        let dir = base.join(format!("case{i}"));
        let cfg = config(&dir, body);
        let text_line = body.lines().nth(line - 1).unwrap();
        let col = text_line.find(token).unwrap() + 1;
        let at = format!("{}:{col}", line + 6);
        assert_refused(&cfg, &[], &at, key, words, &dir.join("run"));
    }
    // `export.nanovdb: true` takes further keys from --set
    let cfg = config(&base, "export:\n  nanovdb: true\n");
    let o = nimbus()
        .arg("validate")
        .arg(&cfg)
        .args(["--set", "export.nanovdb.precision=fp16"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        err.starts_with(&format!(
            "{}: --set export.nanovdb.precision: fp16 quantises float grids only",
            cfg.display()
        )),
        "{err}"
    );
}
