//! `export.nanovdb` read by NanoVDB's own tools (Debian 12's `libnanovdb-tools`, NanoVDB 32.4,
//! installed by tools/setup.sh): `nanovdb_validate` passes every grid of every file,
//! `nanovdb_print` lists them, the values of every active voxel equal the VDB file's of the same
//! frame (bit for bit in float, within the quantiser's bound otherwise; the `.nvdb` converted
//! back by `nanovdb_convert` and read with pyopenvdb), and the files are byte for byte what
//! `nanovdb_convert -c full` makes of nimbus's VDB file. From `run`, and from `nimbus export`
//! with the run's own settings and with other ones.
mod common;
use common::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn fresh(name: &str) -> PathBuf {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&out);
    out
}

/// Whether NanoVDB's command-line tools run here. Under CI=true (where .ci/run installs them
/// with tools/setup.sh) a missing tool fails the test instead of skipping it.
fn nanovdb_tools() -> bool {
    let ok = ["nanovdb_validate", "nanovdb_print", "nanovdb_convert"]
        .iter()
        .all(|t| Command::new(t).arg("--version").output().is_ok());
    if !ok && std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but NanoVDB's tools are missing: CI must install libnanovdb-tools (tools/setup.sh)");
    }
    ok
}

fn tool(name: &str, args: &[&std::ffi::OsStr]) -> Output {
    let o = Command::new(name).args(args).output().unwrap();
    assert!(o.status.success(), "{name} {args:?}: {}", text(&o));
    o
}

/// The segments of a NanoVDB file (header, grid record, buffer), by grid name.
fn segments(bytes: &[u8]) -> Vec<(String, Vec<u8>)> {
    let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    let mut out = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let count = u16::from_le_bytes([bytes[at + 12], bytes[at + 13]]);
        assert_eq!(count, 1, "one grid per segment, as nanovdb_convert writes");
        let meta = at + 16;
        let size = u64_at(meta + 8) as usize;
        let name_size = u32::from_le_bytes(bytes[meta + 136..meta + 140].try_into().unwrap());
        let name = String::from_utf8_lossy(&bytes[meta + 176..meta + 175 + name_size as usize]);
        let end = meta + 176 + name_size as usize + size;
        out.push((name.into_owned(), bytes[at..end].to_vec()));
        at = end;
    }
    out
}

/// `nanovdb_validate -v` passes every grid of `file` (it prints "failed" and still exits 0
/// when one does not).
fn validate(file: &Path, grids: &[&str]) {
    let o = tool("nanovdb_validate", &["-v".as_ref(), file.as_os_str()]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(!out.contains("failed"), "{}: {out}", file.display());
    for g in grids {
        assert!(
            out.contains(&format!("Grid named \"{g}\": passed")),
            "{}: {out}",
            file.display()
        );
    }
}

/// The NanoVDB file converted back to OpenVDB by `nanovdb_convert` holds the VDB file's active
/// voxels with their values (`spec`: tests/data/compare_vdb_values.py).
fn same_values(vdb: &Path, nvdb: &Path, spec: serde_json::Value) {
    let back = nvdb.with_extension("back.vdb");
    tool(
        "nanovdb_convert",
        &["-f".as_ref(), nvdb.as_os_str(), back.as_os_str()],
    );
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/compare_vdb_values.py");
    let o = Command::new("/usr/bin/python3")
        .arg(script)
        .arg(vdb)
        .arg(&back)
        .arg(spec.to_string())
        .output()
        .unwrap();
    eprint!("{}", String::from_utf8_lossy(&o.stdout));
    assert!(o.status.success(), "{}: {}", nvdb.display(), text(&o));
    std::fs::remove_file(back).unwrap();
}

fn export(run: &Path, args: &[&str]) {
    let o = nimbus().arg("export").arg(run).args(args).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
}

const GRIDS: [&str; 4] = ["density", "temperature", "vapor", "vel"];

#[test]
fn nanovdb_files_are_valid_and_hold_the_vdb_values() {
    if !nanovdb_tools() || !pyopenvdb_available() {
        eprintln!("note: NanoVDB's tools or pyopenvdb missing (tools/setup.sh); skipping");
        return;
    }
    let run = fresh("nanovdb_run");
    // Cloudy from the first frame, so the density grid is not empty.
    let o = run_tiny(
        &run,
        &[
            "--set",
            "output.frames.end=4",
            "--set",
            "physics.initial_vapor=1.01",
            "--set",
            "export.nanovdb=true",
            "--set",
            "export.particles=true",
        ],
    );
    assert!(o.status.success(), "{}", text(&o));
    let m = manifest(&run);
    for rec in m["frames"].as_array().unwrap() {
        let f = rec["frame"].as_u64().unwrap();
        let nv = &rec["files"][1];
        assert_eq!(nv["path"], format!("nvdb/tiny.{f:04}.nvdb"), "{rec}");
        let bytes = std::fs::read(run.join(nv["path"].as_str().unwrap())).unwrap();
        assert_eq!(nv["bytes"], bytes.len() as u64);
        assert_eq!(
            nv["sha256"],
            nimbus::pipeline::records::sha256_hex(&bytes).as_str()
        );
        validate(&run.join(nv["path"].as_str().unwrap()), &GRIDS);
    }
    let nvdb = |dir: &Path, f: u32| dir.join(format!("nvdb/tiny.{f:04}.nvdb"));
    let vdb = |dir: &Path, f: u32| dir.join(format!("vdb/tiny.{f:04}.vdb"));

    let o = tool("nanovdb_print", &[nvdb(&run, 4).as_os_str()]);
    let listing = String::from_utf8_lossy(&o.stdout);
    for (g, ty, class) in [
        ("density", "float", "FOG"),
        ("temperature", "float", "FOG"),
        ("vapor", "float", "FOG"),
        ("vel", "Vec3f", "?"),
    ] {
        let row = listing
            .lines()
            .find(|l| l.split_whitespace().nth(1) == Some(g))
            .unwrap_or_else(|| panic!("nanovdb_print lists no {g}:\n{listing}"));
        let cols: Vec<&str> = row.split_whitespace().collect();
        assert_eq!((cols[2], cols[3]), (ty, class), "{row}");
    }

    // nimbus's own reader agrees: every checksum, and the active voxels nanovdb_print counts
    let o = nimbus().arg("inspect").arg(nvdb(&run, 4)).output().unwrap();
    let described = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(described.matches("checksum ok").count(), 4, "{described}");

    let exact = json!({"density": {}, "temperature": {}, "vapor": {}, "vel": {}});
    for f in [1, 4] {
        same_values(&vdb(&run, f), &nvdb(&run, f), exact.clone());
        // byte for byte what NanoVDB's converter makes of the VDB file
        let reference = run.join(format!("ref.{f}.nvdb"));
        tool(
            "nanovdb_convert",
            &[
                "-f".as_ref(),
                "-c".as_ref(),
                "full".as_ref(),
                vdb(&run, f).as_os_str(),
                reference.as_os_str(),
            ],
        );
        assert!(
            std::fs::read(&reference).unwrap() == std::fs::read(nvdb(&run, f)).unwrap(),
            "frame {f}: differs from nanovdb_convert -c full of the VDB"
        );
        std::fs::remove_file(reference).unwrap();
    }

    // `nimbus export` with the run's own settings makes a lost file again, byte for byte.
    let before = std::fs::read(nvdb(&run, 3)).unwrap();
    std::fs::remove_file(nvdb(&run, 3)).unwrap();
    export(&run, &["--frames", "3"]);
    assert!(std::fs::read(nvdb(&run, 3)).unwrap() == before);

    // Quantised, from the particle caches into an export directory: one precision per grid.
    let q = run.join("exports/q");
    export(
        &run,
        &[
            "--frames",
            "3-4",
            "--set",
            "export.nanovdb.grids={density: fp8, temperature: fp16, vapor: fpn, vel: float}",
            "--set",
            "export.nanovdb.tolerance=0.002",
            "--name",
            "q",
        ],
    );
    let o = tool("nanovdb_print", &[nvdb(&q, 4).as_os_str()]);
    let listing = String::from_utf8_lossy(&o.stdout);
    for (g, ty) in [
        ("density", "Float8"),
        ("temperature", "Float16"),
        ("vapor", "FloatN"),
        ("vel", "Vec3f"),
    ] {
        assert!(
            listing
                .lines()
                .any(|l| l.split_whitespace().nth(1) == Some(g)
                    && l.split_whitespace().nth(2) == Some(ty)),
            "{g} {ty}:\n{listing}"
        );
    }
    validate(&nvdb(&q, 4), &GRIDS);
    // FpN's absolute tolerance: 0.002 of the vapor grid's range in this frame.
    let vapor = match nimbus::io::vdb::read_file(&vdb(&q, 4))
        .unwrap()
        .grid("vapor")
        .map(|g| g.data.clone())
    {
        Some(nimbus::io::vdb::GridData::Float(g)) => g,
        _ => panic!("no vapor grid"),
    };
    let tol = nimbus::pipeline::writer::fpn_tolerance(&vapor, 0.002);
    assert!(tol > 0.0);
    same_values(
        &vdb(&q, 4),
        &nvdb(&q, 4),
        json!({"density": {"bits": 8}, "temperature": {"bits": 16},
               "vapor": {"tolerance": tol}, "vel": {}}),
    );
    // Each grid is the segment nanovdb_convert writes for it with the same quantiser.
    let ours = segments(&std::fs::read(nvdb(&q, 4)).unwrap());
    let q_vdb = vdb(&q, 4);
    let abs = format!("{tol:.8e}");
    for (g, flags) in [
        ("density", vec!["--fp8"]),
        ("temperature", vec!["--fp16"]),
        ("vapor", vec!["-a", abs.as_str()]),
        ("vel", vec![]),
    ] {
        let reference = q.join(format!("ref_{g}.nvdb"));
        let mut args: Vec<&std::ffi::OsStr> = vec!["-f".as_ref(), "-c".as_ref(), "full".as_ref()];
        args.extend(flags.iter().map(std::ffi::OsStr::new));
        args.extend([
            "-g".as_ref(),
            g.as_ref(),
            q_vdb.as_os_str(),
            reference.as_os_str(),
        ]);
        tool("nanovdb_convert", &args);
        let theirs = std::fs::read(&reference).unwrap();
        let mine = &ours.iter().find(|(n, _)| n == g).unwrap().1;
        assert!(
            *mine == theirs,
            "{g}: differs from nanovdb_convert {flags:?}"
        );
        std::fs::remove_file(reference).unwrap();
    }

    // Fp4 for the float grids named in a list.
    export(
        &run,
        &[
            "--frames",
            "4",
            "--set",
            "export.nanovdb.precision=fp4",
            "--set",
            "export.nanovdb.grids=[density, vapor]",
            "--name",
            "q4",
        ],
    );
    let q4 = run.join("exports/q4");
    validate(&nvdb(&q4, 4), &["density", "vapor"]);
    same_values(
        &vdb(&q4, 4),
        &nvdb(&q4, 4),
        json!({"density": {"bits": 4}, "vapor": {"bits": 4}}),
    );
    let names: Vec<String> = segments(&std::fs::read(nvdb(&q4, 4)).unwrap())
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    assert_eq!(names, ["density", "vapor"]);
}

/// Killed while renaming frame 3's NanoVDB file into place, then resumed: every file, the
/// NanoVDB files and the USD layer included, is byte-identical to an uninterrupted run, and no
/// half-written file is left.
#[test]
fn a_run_killed_while_writing_nanovdb_resumes_to_the_same_bytes() {
    let base = fresh("nanovdb_resume");
    let sets = [
        "--set",
        "output.frames.end=4",
        "--set",
        "export.nanovdb={enabled: true, grids: {density: fp8, vel: float}}",
        "--set",
        "export.usd=true",
    ];
    let whole = base.join("whole");
    let o = run_tiny(&whole, &sets);
    assert!(o.status.success(), "{}", text(&o));

    let run = base.join("killed");
    let o = nimbus()
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&run)
        .args(sets)
        .env("NIMBUS_FAULT", "rename:tiny.0003.nvdb:1")
        .output()
        .unwrap();
    assert!(
        !o.status.success(),
        "the fault did not stop the run: {}",
        text(&o)
    );
    assert!(!run.join("nvdb/tiny.0003.nvdb").exists());
    let o = nimbus().arg("resume").arg(&run).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(checksums(&run), checksums(&whole));
    assert_eq!(manifest(&run)["usd"], manifest(&whole)["usd"]);
    for f in ["nvdb/tiny.0003.nvdb", "nvdb/tiny.0004.nvdb", "tiny.usda"] {
        assert!(
            std::fs::read(run.join(f)).unwrap() == std::fs::read(whole.join(f)).unwrap(),
            "{f} differs"
        );
    }
    let leftovers: Vec<_> = std::fs::read_dir(run.join("nvdb"))
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".nimbus-tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}
