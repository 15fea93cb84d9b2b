//! Error wording and positions of `read_str` / `read`.
use super::*;

/// The config [`read_str`] gives: the tests here are of the config's own checks.
fn load_str(text: &str, origin: &str, sets: &[String]) -> Result<ShotConfig> {
    read_str(text, origin, sets).map(|c| c.config)
}

fn load(path: &Path, sets: &[String]) -> Result<ShotConfig> {
    read(path, sets).map(|c| c.config)
}

const BASE: &str = "\
shot: test
output:
  frames: {start: 1, end: 10}
domain:
  size: [100, 50, 100]
  spacing: 5
";

fn err(text: &str, sets: &[&str]) -> String {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    match load_str(text, "shot.yaml", &sets) {
        Ok(c) => panic!("expected an error, got {c:?}"),
        Err(e) => {
            assert_eq!(e.exit_code(), 2);
            let s = e.to_string();
            assert!(!s.contains('\n'), "more than one line: {s}");
            s
        }
    }
}

fn ok(text: &str, sets: &[&str]) -> ShotConfig {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    load_str(text, "shot.yaml", &sets).unwrap()
}

#[test]
fn base_loads_with_defaults() {
    let c = ok(BASE, &[]);
    assert_eq!(c.shot, "test");
    assert_eq!(c.domain.size, [100.0, 50.0, 100.0]);
    assert_eq!(c.solver, SolverConfig::default());
    assert_eq!(c.domain.periodic, vec![Axis::X, Axis::Z]);
    let d = c.output.preview.sun_direction;
    assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-12);
}

#[test]
fn type_error_names_line_col_key_and_values() {
    let e = err(&format!("{BASE}solver:\n  iterations: four\n"), &[]);
    assert_eq!(
        e,
        "shot.yaml:8:15: solver.iterations: expected an unsigned integer (0, 1, 2, ...), got \"four\""
    );
}

#[test]
fn negative_for_unsigned() {
    let e = err(&format!("{BASE}solver:\n  iterations: -3\n"), &[]);
    assert!(
        e.starts_with("shot.yaml:8:15: solver.iterations: expected an unsigned integer"),
        "{e}"
    );
    assert!(e.ends_with("got -3"), "{e}");
}

#[test]
fn unknown_keys_list_valid_ones() {
    let e = err(&format!("{BASE}solvr:\n  iterations: 3\n"), &[]);
    assert!(
        e.starts_with("shot.yaml:7:1: solvr: unknown key \"solvr\""),
        "{e}"
    );
    assert!(e.contains("solver") && e.contains("physics"), "{e}");
    let e = err(&format!("{BASE}  spacng: 3\n"), &[]);
    assert!(
        e.starts_with("shot.yaml:7:3: domain.spacng: unknown key"),
        "{e}"
    );
    assert!(e.contains("kernel_ratio"), "{e}");
}

#[test]
fn missing_key_names_parent() {
    let e = err(
        "shot: a\noutput:\n  frames: {start: 1}\ndomain: {size: [1,1,1], spacing: 0.1}\n",
        &[],
    );
    assert_eq!(
        e,
        "shot.yaml:3:3: output.frames: missing required key 'end'"
    );
    let e = err("shot: a\noutput:\n  frames: {start: 1, end: 2}\n", &[]);
    assert!(
        e.starts_with("shot.yaml:1:1: (top level): missing required key 'domain'"),
        "{e}"
    );
}

#[test]
fn wrong_enum_value() {
    let e = err(&format!("{BASE}  periodic: [x, y]\n"), &[]);
    assert_eq!(
        e,
        "shot.yaml:7:17: domain.periodic[1]: expected one of x, z, got \"y\""
    );
    let e = err(&format!("{BASE}  periodic: [x, yes]\n"), &[]);
    assert!(
        e.ends_with("domain.periodic[1]: expected one of x, z, got \"yes\""),
        "{e}"
    );
    let e = err(&format!("{BASE}gpu: {{backend: metal}}\n"), &[]);
    assert!(
        e.contains("gpu.backend: expected one of auto, vulkan, gl, got \"metal\""),
        "{e}"
    );
}

#[test]
fn wrong_list_length() {
    let e = err(
        "shot: a\noutput: {frames: {start: 1, end: 2}}\ndomain: {size: [1, 2], spacing: 0.1}\n",
        &[],
    );
    assert!(
        e.starts_with("shot.yaml:3:16: domain.size: expected a list of 3 values, got 2 values"),
        "{e}"
    );
    let e = err("shot: a\noutput: {frames: {start: 1, end: 2}}\ndomain: {size: [1, 2, 3, 4], spacing: 0.1}\n", &[]);
    assert!(
        e.contains("domain.size: too many values: expected 3, got 4"),
        "{e}"
    );
}

#[test]
fn nan_is_rejected_with_its_key() {
    let e = err(&format!("{BASE}solver: {{gravity: .nan}}\n"), &[]);
    assert!(
        e.contains(":7:19: solver.gravity: expected a finite number, got .nan"),
        "{e}"
    );
}

#[test]
fn duplicate_keys_are_errors() {
    let e = err(&format!("{BASE}  spacing: 4\n"), &[]);
    assert_eq!(
        e,
        "shot.yaml:7:3: domain.spacing: duplicate key (first given at line 6:3)"
    );
}

#[test]
fn string_fields_refuse_numbers_with_a_hint() {
    let e = err(&BASE.replace("shot: test", "shot: 0420"), &[]);
    assert!(
        e.starts_with("shot.yaml:1:7: shot: expected a string, got"),
        "{e}"
    );
    assert!(e.contains("quotes"), "{e}");
}

#[test]
fn empty_and_comment_only_files() {
    for text in ["", "   \n", "# nothing here\n"] {
        let e = err(text, &[]);
        assert!(e.starts_with("shot.yaml: the file is empty"), "{e}");
    }
}

#[test]
fn top_level_must_be_a_mapping() {
    let e = err("- a\n- b\n", &[]);
    assert!(e.contains("(top level): expected a mapping of keys"), "{e}");
}

#[test]
fn syntax_errors_have_position_and_nearby_key() {
    let e = err(
        &format!("{BASE}solver:\n  iterations: [1, 2\n  gravity: 3\n"),
        &[],
    );
    assert!(e.starts_with("shot.yaml:"), "{e}");
    assert!(e.contains("invalid YAML"), "{e}");
    let e = err("shot: a\noutput:\n\tframes: {start: 1, end: 2}\n", &[]);
    assert!(e.starts_with("shot.yaml:3:"), "{e}");
    assert!(e.contains(" output.frames: "), "{e}");
    assert!(e.contains("tabs"), "{e}");
    let e = err("shot: a\ndomain:\n  size: [1, 2, 3\n  spacing: 1\n", &[]);
    assert!(e.contains("(is the '[' at line 3:9 closed?)"), "{e}");
}

#[test]
fn validation_errors_point_at_the_key() {
    let e = err(&BASE.replace("end: 10", "end: 0"), &[]);
    assert_eq!(
        e,
        "shot.yaml:3:22: output.frames.end: end frame 0 is before start frame 1"
    );
    let e = err(&format!("{BASE}adaptive:\n  merge_threshold: 0.7\n"), &[]);
    assert!(
        e.starts_with(
            "shot.yaml:8:3: adaptive.merge_threshold: merge_threshold (0.7) must be below"
        ),
        "{e}"
    );
    // A default key is named without a position.
    let e = err(&format!("{BASE}output2: 1\n"), &[]);
    assert!(e.contains("output2: unknown key"), "{e}");
}

#[test]
fn overrides_apply_before_validation() {
    let c = ok(
        BASE,
        &[
            "output.frames.end=20",
            "domain.size=[200,60,100]",
            "solver.gravity=9.81",
        ],
    );
    assert_eq!(c.output.frames.end, 20);
    assert_eq!(c.domain.size, [200.0, 60.0, 100.0]);
    assert_eq!(c.solver.gravity, 9.81);
    let c = ok(BASE, &["domain.size[1]=70", "domain.size.2=80"]);
    assert_eq!(c.domain.size, [100.0, 70.0, 80.0]);
    let c = ok(BASE, &["export.grids.aliases.heat=temperature"]);
    assert_eq!(c.export.grids.aliases["heat"], "temperature");
    // Later overrides win.
    let c = ok(BASE, &["seed=3", "seed=4"]);
    assert_eq!(c.seed, 4);
    // An override can fix an invalid file.
    ok(&BASE.replace("end: 10", "end: 0"), &["output.frames.end=5"]);
}

#[test]
fn bad_overrides_name_the_set() {
    let e = err(BASE, &["solver.iterations=four"]);
    assert_eq!(
        e,
        "shot.yaml: --set solver.iterations: expected an unsigned integer (0, 1, 2, ...), got \"four\""
    );
    let e = err(BASE, &["solver.iteratons=4"]);
    assert!(
        e.starts_with("shot.yaml: --set solver.iteratons: unknown key \"iteratons\""),
        "{e}"
    );
    let e = err(BASE, &["output.frames.end"]);
    assert!(
        e.contains("--set output.frames.end: expected KEY.PATH=VALUE"),
        "{e}"
    );
    let e = err(BASE, &["shot.name=x"]);
    assert!(
        e.contains("--set shot.name: cannot set it: shot is \"test\", not a mapping"),
        "{e}"
    );
    let e = err(BASE, &["domain.size[5]=1"]);
    assert!(
        e.contains("--set domain.size[5]: index 5 is past the end of domain.size"),
        "{e}"
    );
    let e = err(BASE, &["domain.size=[1,2"]);
    assert!(
        e.contains("--set domain.size: cannot read the value"),
        "{e}"
    );
    let e = err(BASE, &["output.frames.end=0"]);
    assert_eq!(
        e,
        "shot.yaml: --set output.frames.end: end frame 0 is before start frame 1"
    );
    let e = err(BASE, &["domain={size: [1, 1, 1], spacing: x}"]);
    assert!(
        e.contains("--set domain: domain.spacing: expected a number, got \"x\""),
        "{e}"
    );
    let e = err(BASE, &["=3"]);
    assert!(
        e.contains("--set : empty key segment") || e.contains("empty key"),
        "{e}"
    );
}

#[test]
fn load_reports_files_that_are_not_text() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.yaml");
    let e = load(&missing, &[]).unwrap_err().to_string();
    assert!(
        e.ends_with("nope.yaml: cannot read config: no such file"),
        "{e}"
    );
    let bin = dir.path().join("bin.yaml");
    std::fs::write(&bin, b"shot: a\n\xff\xfe\x00garbage").unwrap();
    let e = load(&bin, &[]).unwrap_err().to_string();
    assert!(
        e.contains("bin.yaml:2:1: not UTF-8 text (byte 0xff at offset 8)"),
        "{e}"
    );
    let nul = dir.path().join("nul.yaml");
    std::fs::write(&nul, b"shot: a\x00\n").unwrap();
    let e = load(&nul, &[]).unwrap_err().to_string();
    assert!(e.contains("nul.yaml:1:8: binary data"), "{e}");
    let e = load(dir.path(), &[]).unwrap_err().to_string();
    assert!(e.contains("cannot read config"), "{e}");
}

#[test]
fn random_input_never_panics() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let alphabet = b"abc:- \n\t[]{},#&*!|>'\"%@`?.0123456789e+";
    for round in 0..3000 {
        let len = rng.random_range(0..200);
        let text: String = if round % 2 == 0 {
            (0..len)
                .map(|_| alphabet[rng.random_range(0..alphabet.len())] as char)
                .collect()
        } else {
            // Mutate a valid config.
            let mut b: Vec<char> = BASE.chars().collect();
            for _ in 0..rng.random_range(1..6) {
                let i = rng.random_range(0..b.len());
                b[i] = alphabet[rng.random_range(0..alphabet.len())] as char;
            }
            b.into_iter().collect()
        };
        if let Err(e) = load_str(&text, "fuzz.yaml", &[]) {
            let s = e.to_string();
            assert!(s.starts_with("fuzz.yaml"), "{s}");
            assert!(!s.contains('\n'), "{s}");
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("r.yaml");
    for _ in 0..300 {
        let len = rng.random_range(0..300);
        let bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
        std::fs::write(&p, &bytes).unwrap();
        if let Err(e) = load(&p, &[]) {
            assert!(!e.to_string().contains('\n'));
        }
    }
}

#[test]
fn deep_nesting_is_an_error_not_a_crash() {
    let text = format!("shot: {}{}\n", "[".repeat(5000), "]".repeat(5000));
    let e = err(&text, &[]);
    assert!(e.starts_with("shot.yaml"), "{e}");
}

#[test]
fn key_near_follows_indentation() {
    let t = "a:\n  b:\n    c: 1\n  d: [\n";
    assert_eq!(key_near(t, 3).as_deref(), Some("a.b.c"));
    assert_eq!(key_near(t, 4).as_deref(), Some("a.d"));
}

#[test]
fn parse_key_paths() {
    assert_eq!(
        parse_key("a.b[2].c").unwrap(),
        vec![
            Seg::Key("a".into()),
            Seg::Key("b".into()),
            Seg::Index(2),
            Seg::Key("c".into())
        ]
    );
    assert_eq!(
        parse_key("a.1").unwrap(),
        vec![Seg::Key("a".into()), Seg::Index(1)]
    );
    assert!(parse_key("a..b").is_err());
    assert!(parse_key("a[x]").is_err());
    assert!(parse_key("").is_err());
}

#[test]
fn public_validate_names_keys() {
    let mut c = ok(BASE, &[]);
    assert!(validate(&c).is_ok());
    c.output.substeps = 0;
    let e = validate(&c).unwrap_err().to_string();
    assert!(
        e.starts_with("output.substeps: expected an integer from 1"),
        "{e}"
    );
}

#[test]
fn decimals_for_integers_show_the_decimal() {
    let e = err(&format!("{BASE}solver: {{iterations: 4.0}}\n"), &[]);
    assert!(
        e.ends_with("solver.iterations: expected an unsigned integer (0, 1, 2, ...), got 4.0"),
        "{e}"
    );
    let e = err(&format!("{BASE}solver: {{rest_density: -2.0}}\n"), &[]);
    assert!(
        e.ends_with("solver.rest_density: expected a number in (0, 1e4], got -2"),
        "{e}"
    );
}

#[test]
fn empty_section_takes_defaults() {
    let c = ok(
        &format!("{BASE}solver:\nadaptive: {{}}\n"),
        &["physics.smoothing.kappa=0.3"],
    );
    assert_eq!(c.solver, SolverConfig::default());
    assert_eq!(c.physics.smoothing.kappa, 0.3);
}

/// docs/CONFIG.md must document every key of the schema (leaf keys, `[..]` lists as a whole).
#[test]
fn every_key_is_documented() {
    fn leaves(v: &serde_json::Value, path: &str, out: &mut Vec<String>) {
        match v {
            serde_json::Value::Object(m) if !path.ends_with("aliases") => {
                for (k, x) in m {
                    let p = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    leaves(x, &p, out);
                }
            }
            _ => out.push(path.to_string()),
        }
    }
    let mut c = ok(BASE, &[]);
    c.output.preview.camera = Some(CameraConfig {
        position: [0.0, 1.0, 2.0],
        look_at: [1.0, 1.0, 1.0],
        fov_deg: 45.0,
    });
    // serialised only when on
    c.output.preview.source_overlay = true;
    c.export.usd = true;
    c.export.nanovdb.enabled = true;
    let mut keys = Vec::new();
    leaves(&serde_json::to_value(&c).unwrap(), "", &mut keys);
    assert!(keys.len() > 60, "{keys:?}");
    let doc =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/CONFIG.md")).unwrap();
    for k in keys {
        assert!(
            doc.contains(&format!("| `{k}` |")),
            "docs/CONFIG.md lacks a row for `{k}`"
        );
    }
}

#[test]
fn heat_source_schedule_ramps_in_and_out() {
    let src = HeatSource {
        start: 100.0,
        end: Some(300.0),
        ramp: 50.0,
        ..HeatSource::disc(0.0, 0.0, 100.0, 1.0)
    };
    assert_eq!(src.envelope(99.0), 0.0);
    assert_eq!(src.envelope(125.0), 0.5);
    assert_eq!(src.envelope(200.0), 1.0);
    assert_eq!(src.envelope(275.0), 0.5);
    assert_eq!(src.envelope(301.0), 0.0);
    let always = HeatSource {
        end: None,
        ramp: 0.0,
        start: 0.0,
        ..src
    };
    assert_eq!(always.envelope(0.0), 1.0);
    assert_eq!(always.envelope(1e6), 1.0);
    // the falloff: full strength inside 0.7 radius, nothing outside
    assert_eq!(HeatSource::falloff(100.0, 60.0, 0.0), 1.0);
    assert_eq!(HeatSource::falloff(100.0, 0.0, 100.0), 0.0);
    let mid = HeatSource::falloff(100.0, 85.0, 0.0);
    assert!((mid - 0.5).abs() < 1e-12, "{mid}");
}

#[test]
fn nanovdb_takes_a_bool_or_a_mapping_and_grids_a_list_or_a_mapping() {
    let on = ok(&format!("{BASE}export:\n  nanovdb: true\n"), &[]);
    assert!(on.export.nanovdb.enabled);
    assert_eq!(on.export.nanovdb.precision, NanoPrecision::Float);
    // a key under the shorthand, from --set
    let fp = ok(
        &format!("{BASE}export:\n  nanovdb: true\n"),
        &["export.nanovdb.grids={density: fp8, vel: float}"],
    );
    assert!(fp.export.nanovdb.enabled);
    assert_eq!(
        fp.export.nanovdb.grids.0,
        vec![
            ("density".to_string(), Some(NanoPrecision::Fp8)),
            ("vel".to_string(), Some(NanoPrecision::Float))
        ]
    );
    let list = ok(
        BASE,
        &["export.nanovdb={enabled: true, precision: fp16, grids: [temperature, density]}"],
    );
    assert_eq!(list.export.nanovdb.precision, NanoPrecision::Fp16);
    assert_eq!(
        list.export.nanovdb.grids.0,
        vec![
            ("temperature".to_string(), None),
            ("density".to_string(), None)
        ]
    );
    // the manifest's JSON loads back to the same config; unset, nothing is serialised
    for c in [&fp, &list] {
        let json = serde_json::to_string(c).unwrap();
        assert_eq!(&ok(&json, &[]), c);
    }
    let off = serde_json::to_value(ok(BASE, &[])).unwrap();
    assert!(off["export"].get("nanovdb").is_none() && off["export"].get("usd").is_none());
    // file order, each grid with its precision
    let sel: Vec<(String, NanoPrecision)> = crate::export::nanovdb_grids(&fp.export)
        .into_iter()
        .map(|(g, p)| (g.name, p))
        .collect();
    assert_eq!(
        sel,
        vec![
            ("density".to_string(), NanoPrecision::Fp8),
            ("vel".to_string(), NanoPrecision::Float)
        ]
    );
    assert!(err(BASE, &["export.nanovdb=[1]"]).contains("expected true, false or a mapping"));
}
