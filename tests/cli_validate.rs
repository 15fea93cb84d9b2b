//! `nimbus validate` through the real binary: every malformed config under tests/configs/bad/
//! exits 2 with exactly one stderr line naming the file, the line:col (where the file has one)
//! and the key path.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn nimbus(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args)
        .current_dir(root())
        .output()
        .expect("run nimbus")
}

fn stderr_lines(o: &Output) -> Vec<String> {
    String::from_utf8_lossy(&o.stderr)
        .lines()
        .map(str::to_string)
        .collect()
}

/// (file, line:col expected in the message or None where the problem has no position,
///  key path the message must name or None where there is no key).
const BAD: &[(&str, Option<&str>, Option<&str>)] = &[
    ("type_error.yaml", Some(":8:15:"), Some("solver.iterations")),
    ("unknown_top_key.yaml", Some(":7:1:"), Some("solvr")),
    (
        "unknown_nested_key.yaml",
        Some(":9:5:"),
        Some("physics.smoothing.kapa"),
    ),
    (
        "missing_required.yaml",
        Some(":3:3:"),
        Some("output.frames"),
    ),
    ("missing_section.yaml", Some(":1:1:"), Some("(top level)")),
    (
        "out_of_range_kappa.yaml",
        Some(":9:5:"),
        Some("physics.smoothing.kappa"),
    ),
    (
        "end_before_start.yaml",
        Some(":3:23:"),
        Some("output.frames.end"),
    ),
    ("zero_substeps.yaml", Some(":4:3:"), Some("output.substeps")),
    (
        "kernel_larger_than_domain.yaml",
        Some(":6:3:"),
        Some("domain.spacing"),
    ),
    (
        "thresholds_inverted.yaml",
        Some(":10:3:"),
        Some("adaptive.merge_threshold"),
    ),
    ("syntax_error.yaml", Some(":6:10:"), Some("domain.spacing")),
    ("empty.yaml", None, None),
    ("tabs.yaml", Some(":3:2:"), Some("output.frames")),
    ("duplicate_key.yaml", Some(":7:3:"), Some("domain.spacing")),
    (
        "wrong_enum.yaml",
        Some(":9:18:"),
        Some("export.vdb.compression"),
    ),
    (
        "negative_unsigned.yaml",
        Some(":3:19:"),
        Some("output.frames.start"),
    ),
    (
        "negative_spacing.yaml",
        Some(":6:3:"),
        Some("domain.spacing"),
    ),
    (
        "periodic_too_small.yaml",
        Some(":7:3:"),
        Some("domain.periodic"),
    ),
    ("nan_value.yaml", Some(":5:15:"), Some("domain.size[1]")),
    ("wrong_list_length.yaml", Some(":5:9:"), Some("domain.size")),
    (
        "too_many_particles.yaml",
        Some(":6:3:"),
        Some("domain.spacing"),
    ),
    (
        "padding_too_small.yaml",
        Some(":4:3:"),
        Some("output.frame_padding"),
    ),
    ("empty_adapter.yaml", Some(":8:3:"), Some("gpu.adapter")),
    (
        "capacity_below_one.yaml",
        Some(":8:3:"),
        Some("adaptive.capacity_factor"),
    ),
    ("zero_voxel.yaml", Some(":8:3:"), Some("export.voxel_size")),
    ("top_level_list.yaml", Some(":1:1:"), Some("(top level)")),
    ("binary_garbage.yaml", Some(":1:1:"), None),
    ("string_for_list.yaml", Some(":5:9:"), Some("domain.size")),
];

#[test]
fn every_bad_config_exits_2_with_one_precise_line() {
    let dir = root().join("tests/configs/bad");
    let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    on_disk.sort();
    let mut listed: Vec<String> = BAD.iter().map(|(f, _, _)| f.to_string()).collect();
    listed.sort();
    assert_eq!(
        on_disk, listed,
        "every file in tests/configs/bad has a row in BAD"
    );
    assert!(BAD.len() >= 15);

    for (file, pos, key) in BAD {
        let rel = format!("tests/configs/bad/{file}");
        let o = nimbus(&["validate", &rel]);
        let lines = stderr_lines(&o);
        assert_eq!(o.status.code(), Some(2), "{file}: {lines:?}");
        assert_eq!(lines.len(), 1, "{file}: one stderr line, got {lines:?}");
        let line = &lines[0];
        assert!(line.contains(&rel), "{file}: names the file: {line}");
        if let Some(pos) = pos {
            assert!(
                line.contains(&format!("{rel}{pos}")),
                "{file}: position {pos}: {line}"
            );
        }
        if let Some(key) = key {
            assert!(
                line.contains(&format!(" {key}:")),
                "{file}: key {key}: {line}"
            );
        }
        assert!(o.stdout.is_empty(), "{file}: nothing on stdout");
    }
}

#[test]
fn valid_sample_exits_0() {
    let o = nimbus(&["validate", "samples/minimal.yaml"]);
    assert_eq!(o.status.code(), Some(0), "{:?}", stderr_lines(&o));
    assert!(o.stderr.is_empty());
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("samples/minimal.yaml: ok"), "{out}");
}

#[test]
fn good_overrides_are_applied() {
    let o = nimbus(&[
        "validate",
        "samples/minimal.yaml",
        "--set",
        "output.frames.end=10",
        "--set",
        "domain.size=[100,50,100]",
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", stderr_lines(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("frames 1..=10"), "{out}");
}

#[test]
fn an_override_can_repair_a_bad_value() {
    let o = nimbus(&[
        "validate",
        "tests/configs/bad/zero_substeps.yaml",
        "--set",
        "output.substeps=4",
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", stderr_lines(&o));
}

#[test]
fn bad_overrides_exit_2_naming_the_set() {
    for (set, key) in [
        ("solver.iterations=four", "--set solver.iterations:"),
        ("solver.iteratons=4", "--set solver.iteratons:"),
        ("output.frames.end=0", "--set output.frames.end:"),
        ("domain.size=[1,2", "--set domain.size:"),
        ("novalue", "--set novalue:"),
    ] {
        let o = nimbus(&["validate", "samples/minimal.yaml", "--set", set]);
        let lines = stderr_lines(&o);
        assert_eq!(o.status.code(), Some(2), "{set}: {lines:?}");
        assert_eq!(lines.len(), 1, "{set}: {lines:?}");
        assert!(lines[0].contains("samples/minimal.yaml"), "{}", lines[0]);
        assert!(lines[0].contains(key), "{set}: {}", lines[0]);
    }
}

#[test]
fn missing_file_exits_2() {
    let o = nimbus(&["validate", "tests/configs/does_not_exist.yaml"]);
    let lines = stderr_lines(&o);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert!(
        lines[0].contains("tests/configs/does_not_exist.yaml: cannot read config: no such file")
    );
}

#[test]
fn several_files_report_each_and_exit_2() {
    let o = nimbus(&[
        "validate",
        "samples/minimal.yaml",
        "tests/configs/bad/type_error.yaml",
        "tests/configs/bad/empty.yaml",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(stderr_lines(&o).len(), 2);
    assert!(String::from_utf8_lossy(&o.stdout).contains("minimal.yaml: ok"));
}

#[test]
fn pipelines_and_samples_validate() {
    let mut files: Vec<PathBuf> = Vec::new();
    for dir in ["pipelines", "samples"] {
        let Ok(rd) = std::fs::read_dir(root().join(dir)) else {
            continue;
        };
        for e in rd {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "yaml") {
                files.push(p);
            }
        }
    }
    assert!(files
        .iter()
        .any(|p| p.ends_with(Path::new("samples/minimal.yaml"))));
    for f in files {
        let o = nimbus(&["validate", f.to_str().unwrap()]);
        assert_eq!(
            o.status.code(),
            Some(0),
            "{}: {:?}",
            f.display(),
            stderr_lines(&o)
        );
    }
}

/// Case 3 of issue 13: a device, a FIFO (with a writer feeding it forever), a directory and a
/// file over 1 MiB are one-line errors with exit 2, within a second, without reading them.
#[test]
fn configs_must_be_bounded_regular_files() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("fifo.yaml");
    let ok = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(ok.success());
    // A writer that never stops (it ends when the FIFO's reader side is gone or at test end).
    let mut feeder = Command::new("sh")
        .arg("-c")
        .arg(format!("yes 'a: 1' > '{}'", fifo.display()))
        .spawn()
        .unwrap();
    let big = dir.path().join("big.yaml");
    std::fs::write(&big, "# x\n".repeat(300_000)).unwrap();
    let cases = [
        ("/dev/zero".to_string(), "not a regular file"),
        ("/dev/urandom".to_string(), "not a regular file"),
        (fifo.display().to_string(), "not a regular file"),
        (dir.path().display().to_string(), "is a directory"),
        (big.display().to_string(), "1048576-byte limit"),
    ];
    for (path, why) in cases {
        let t0 = std::time::Instant::now();
        let o = nimbus(&["validate", &path]);
        let secs = t0.elapsed().as_secs_f64();
        let lines = stderr_lines(&o);
        assert_eq!(o.status.code(), Some(2), "{path}: {lines:?}");
        assert_eq!(lines.len(), 1, "{path}: {lines:?}");
        assert!(lines[0].starts_with(&format!("{path}: ")), "{lines:?}");
        assert!(lines[0].contains(why), "{path}: {lines:?}");
        assert!(secs < 1.0, "{path} took {secs} s");
    }
    let _ = feeder.kill();
    let _ = feeder.wait();
}

/// A flag value outside its choices is one line naming the flag, the value and the choices,
/// exit 2, before anything runs.
#[test]
fn a_flag_value_outside_its_choices_exits_2_with_one_line() {
    for (args, want) in [
        (
            "run samples/tiny.yaml --log-format xml",
            r#"--log-format "xml": expected human or json"#,
        ),
        (
            "bench vdb --compression lz4",
            r#"--compression "lz4": expected none, zip or blosc"#,
        ),
        (
            "farm status nowhere --log-format=",
            "--log-format: a value is required: human or json",
        ),
        (
            "resume nowhere --log-format JSON",
            r#"--log-format "JSON": expected human or json"#,
        ),
    ] {
        let o = nimbus(&args.split(' ').collect::<Vec<_>>());
        assert_eq!(o.status.code(), Some(2), "{args}: {:?}", stderr_lines(&o));
        assert_eq!(stderr_lines(&o), [format!("error: {want}")], "{args}");
    }
}

/// A reader that closes its end early (`nimbus validate ... | head -1`) ends the command quietly
/// (exit 0, no panic on stderr); a full disk on standard output is a one-line exit 3.
#[test]
fn a_closed_or_full_stdout_is_not_a_panic() {
    let configs: Vec<String> = (0..2000)
        .map(|_| root().join("samples/tiny.yaml").display().to_string())
        .collect();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .arg("validate")
        .args(&configs)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // read one line, then close the pipe while nimbus still has ~2000 lines to write
    let mut first = String::new();
    {
        let out = child.stdout.take().unwrap();
        std::io::BufRead::read_line(&mut std::io::BufReader::new(out), &mut first).unwrap();
    }
    let o = child.wait_with_output().unwrap();
    assert!(first.contains(": ok ("), "{first}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(!err.contains("panicked"), "{err}");

    if let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_nimbus"))
            .arg("validate")
            .arg(root().join("samples/tiny.yaml"))
            .stdout(full)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(3), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.starts_with("error: writing to standard output"),
            "{err}"
        );
    }
}
