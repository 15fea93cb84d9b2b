//! Helpers shared by the end-to-end tests: run the real binary on a real run directory.
#![allow(dead_code)]
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn nimbus() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nimbus"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    // Mesa's lavapipe warns without it; keep test logs clean.
    let xdg = std::env::temp_dir().join("nimbus-test-xdg");
    let _ = std::fs::create_dir_all(&xdg);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let _ = std::fs::set_permissions(&xdg, std::fs::Permissions::from_mode(0o700));
    }
    c.env("XDG_RUNTIME_DIR", xdg);
    c.env_remove("NIMBUS_FAULT");
    c
}

pub fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("samples")
        .join(name)
}

/// `nimbus run samples/tiny.yaml --out DIR` plus extra arguments.
pub fn run_tiny(out: &Path, extra: &[&str]) -> Output {
    let mut c = nimbus();
    c.arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(out)
        .arg("--log-format")
        .arg("json");
    c.args(extra);
    c.output().expect("nimbus runs")
}

pub fn text(o: &Output) -> String {
    format!(
        "exit {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

pub fn manifest(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap()
}

/// (frame, path, sha256) of a file the manifest records.
pub type Checksum = (u64, String, String);

/// Every file the manifest records.
pub fn checksums(out: &Path) -> Vec<Checksum> {
    let m = manifest(out);
    let mut v = Vec::new();
    for f in m["frames"].as_array().unwrap() {
        for file in f["files"].as_array().unwrap() {
            v.push((
                f["frame"].as_u64().unwrap(),
                file["path"].as_str().unwrap().to_string(),
                file["sha256"].as_str().unwrap().to_string(),
            ));
        }
    }
    v
}

/// stats.jsonl without the timings (which differ run to run).
pub fn stats_without_timings(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("stats.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            v.as_object_mut().unwrap().remove("phase_ms");
            v
        })
        .collect()
}

/// Sends signal `sig` (a name: INT, TERM, HUP, KILL) to a process with kill(1).
#[allow(dead_code)] // not every test binary signals
pub fn kill(pid: u32, sig: &str) {
    let ok = std::process::Command::new("kill")
        .arg(format!("-{sig}"))
        .arg(pid.to_string())
        .status()
        .unwrap();
    assert!(ok.success());
}

/// Whether Blender runs here. Under CI=true (where .ci/run installs it) a missing Blender fails
/// the test instead of skipping it.
pub fn blender_available() -> bool {
    let ok = Command::new("blender")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok && std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but blender is not on PATH: CI must install it (tools/setup.sh --blender)");
    }
    ok
}

/// Whether spirv-val (Debian spirv-tools) runs here. Under CI=true (where .ci/run installs it)
/// a missing one fails the test instead of skipping it.
pub fn spirv_val_available() -> bool {
    let ok = Command::new("spirv-val")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok && std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but spirv-val is not on PATH: CI must install it (tools/setup.sh: spirv-tools)");
    }
    ok
}

/// Whether /usr/bin/python3 has pyopenvdb (the real OpenVDB). Under CI=true (where .ci/run
/// installs python3-openvdb) a missing one fails the test instead of skipping it.
pub fn pyopenvdb_available() -> bool {
    let ok = Command::new("/usr/bin/python3")
        .args(["-c", "import pyopenvdb"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok && std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but /usr/bin/python3 has no pyopenvdb: CI must install python3-openvdb (tools/setup.sh)");
    }
    ok
}

/// Whether /usr/bin/python3 imports every module of `modules` (e.g. numpy, netCDF4). Under
/// CI=true (where .ci/run installs them with tools/setup.sh) a missing one fails the test.
pub fn py_modules_available(modules: &[&str]) -> bool {
    let missing: Vec<&str> = modules
        .iter()
        .copied()
        .filter(|m| {
            !Command::new("/usr/bin/python3")
                .args(["-c", &format!("import {m}")])
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .collect();
    if !missing.is_empty() && std::env::var("CI").as_deref() == Ok("true") {
        panic!(
            "CI=true but /usr/bin/python3 lacks {missing:?}: CI must install them (tools/setup.sh)"
        );
    }
    missing.is_empty()
}

/// Runs tools/render_blender.py headless with `args` (after `--`); returns the process output
/// and the script's `NIMBUS_BLENDER` JSON summary line (a missing line fails the test).
pub fn render_blender<I, S>(args: I) -> (Output, serde_json::Value)
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new("blender")
        .args(["-b", "--factory-startup", "--python-exit-code", "1", "-P"])
        .arg(root.join("tools/render_blender.py"))
        .arg("--")
        .args(args)
        .output()
        .expect("spawn blender");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let summary = stdout
        .lines()
        .find_map(|l| l.strip_prefix("NIMBUS_BLENDER "))
        .unwrap_or_else(|| {
            panic!(
                "no summary line from the script:\n{stdout}\n{}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
    let summary = serde_json::from_str(summary).expect("summary is JSON");
    (out, summary)
}

/// Where tools/setup.sh --farm installs the Open Job Description CLI (PyPI openjd-cli).
pub const OPENJD_VENV: &str = "/opt/nimbus/openjd";

/// The `openjd` command: NIMBUS_OPENJD, else `openjd` on PATH, else the one tools/setup.sh
/// --farm installs in OPENJD_VENV. Under CI=true (where .ci/run installs it) a missing CLI
/// fails the test instead of skipping it.
pub fn openjd_cli() -> Option<PathBuf> {
    let found = std::env::var_os("NIMBUS_OPENJD")
        .map(PathBuf::from)
        .into_iter()
        .chain(
            std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())
                .map(|d| d.join("openjd")),
        )
        .chain([Path::new(OPENJD_VENV).join("bin/openjd")])
        .find(|p| {
            Command::new(p)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        });
    if found.is_none() && std::env::var("CI").as_deref() == Ok("true") {
        panic!(
            "CI=true but the openjd CLI is not installed: CI must install it (tools/setup.sh --farm puts it in {OPENJD_VENV})"
        );
    }
    found
}

/// `validate` and `run` of `cfg` (with `sets` as --set overrides) both exit 2 with one line
/// that starts `CFG:LINE:COL: key: ` (`at` = "LINE:COL") and contains `words`; the run writes
/// nothing at `out`.
#[allow(dead_code)] // not every test crate refuses configs
pub fn assert_refused(cfg: &Path, sets: &[&str], at: &str, key: &str, words: &str, out: &Path) {
    let mut args: Vec<&str> = Vec::new();
    for s in sets {
        args.extend(["--set", s]);
    }
    let o = nimbus()
        .arg("validate")
        .arg(cfg)
        .args(&args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(2), "{}: {}", cfg.display(), text(&o));
    assert_eq!(err.lines().count(), 1, "{err}");
    let want = format!("{}:{at}: {key}: ", cfg.display());
    assert!(err.starts_with(&want), "{err}\nwanted {want}");
    assert!(err.contains(words), "{err} lacks {words:?}");
    let o = nimbus()
        .arg("run")
        .arg(cfg)
        .args(&args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(!out.exists(), "a refused run wrote {}", out.display());
}
