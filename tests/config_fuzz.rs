//! Seeded config fuzz (issue 13): every leaf key of every shipped pipeline and sample is
//! mutated (other types, empty, huge and tiny numbers, NaN and infinities, deep nesting, values
//! scaled around the original). Every mutation must give either `validate` exit 0, or exit 2
//! with one line `FILE[:LINE:COL]: KEY: reason`; never a panic or any other exit code. A seeded
//! sample of the mutations that validate (up to 30k particles: samples and quickstart) is run for one
//! frame, which must succeed: validate never says ok about a shot that run refuses.
//! `NIMBUS_TEST_SEED=N` replays a seed, `NIMBUS_FUZZ_RUNS=N` runs N shots (default 30); the
//! counts are printed.
mod common;
use common::*;
use rand::{Rng, SeedableRng};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Placeholders for what JSON cannot write, replaced by YAML text after serialising.
const RAW: &[(&str, &str)] = &[
    ("__NAN__", ".nan"),
    ("__INF__", ".inf"),
    ("__NINF__", "-.inf"),
    ("__HUGE_INT__", "123456789012345678901234567890"),
    ("__HUGE_FLOAT__", "1e400"),
    ("__DEEP__", ""),
];

fn deep() -> String {
    format!("{}1{}", "[".repeat(200), "]".repeat(200))
}

/// Leaf paths (as JSON pointers and dotted keys) of a parsed config.
fn leaves(v: &Value, ptr: &str, key: &str, out: &mut Vec<(String, String)>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                let key = if key.is_empty() {
                    k.clone()
                } else {
                    format!("{key}.{k}")
                };
                leaves(x, &format!("{ptr}/{k}"), &key, out);
            }
        }
        Value::Array(a) => {
            out.push((ptr.to_string(), key.to_string()));
            for (i, x) in a.iter().enumerate() {
                leaves(x, &format!("{ptr}/{i}"), &format!("{key}[{i}]"), out);
            }
        }
        _ => out.push((ptr.to_string(), key.to_string())),
    }
}

fn mutants(original: &Value, rng: &mut impl Rng) -> Vec<Value> {
    let mut v: Vec<Value> = vec![
        Value::Null,
        "".into(),
        "abc".into(),
        true.into(),
        serde_json::json!([1, 2]),
        serde_json::json!({"a": 1}),
        0.into(),
        (-1).into(),
        1e-50.into(),
        1e50.into(),
        (u32::MAX as u64 + 1).into(),
        u32::MAX.into(),
        "__NAN__".into(),
        "__INF__".into(),
        "__NINF__".into(),
        "__HUGE_INT__".into(),
        "__HUGE_FLOAT__".into(),
        "__DEEP__".into(),
    ];
    if let Some(x) = original.as_f64() {
        for f in [-1.0, 0.5, 2.0, 1e3, 1e-3] {
            v.push((x * f).into());
        }
        v.push((x * rng.random_range(0.0..3.0)).into());
        if let Some(u) = original.as_u64() {
            v.push((u + 1).into());
            v.push(u.saturating_sub(1).into());
        }
    }
    v
}

fn set_ptr(root: &mut Value, ptr: &str, val: Value) {
    *root.pointer_mut(ptr).unwrap() = val;
}

fn to_text(v: &Value) -> String {
    let mut t = serde_json::to_string_pretty(v).unwrap();
    for (ph, raw) in RAW {
        let raw = if *ph == "__DEEP__" {
            deep()
        } else {
            raw.to_string()
        };
        t = t.replace(&format!("\"{ph}\""), &raw);
    }
    t
}

fn shipped() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut v = Vec::new();
    for d in ["pipelines", "samples"] {
        for e in std::fs::read_dir(root.join(d)).unwrap().flatten() {
            if e.path().extension().is_some_and(|x| x == "yaml") {
                v.push(e.path());
            }
        }
    }
    v.sort();
    v
}

/// One result line per file: `FILE: ok (...)` on stdout, or `FILE[:L:C]: KEY: reason` on stderr.
fn check_line(file: &str, line: &str) -> Result<(), String> {
    let rest = line
        .strip_prefix(file)
        .ok_or("does not start with the file")?;
    let rest = rest.strip_prefix(':').ok_or("no ':' after the file")?;
    // Optional LINE:COL:
    let mut parts: Vec<&str> = rest.splitn(3, ':').collect();
    if parts.len() == 3
        && parts[0].chars().all(|c| c.is_ascii_digit())
        && parts[1].chars().all(|c| c.is_ascii_digit())
        && !parts[0].is_empty()
    {
        parts = parts[2].splitn(2, ": ").collect();
    } else {
        parts = rest.splitn(2, ": ").collect();
    }
    let key = parts[0].trim();
    let reason = parts.get(1).copied().unwrap_or("");
    let key_like = !key.is_empty()
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_.[]() ".contains(c));
    if key_like && !reason.trim().is_empty() {
        Ok(())
    } else {
        Err(format!("no KEY: reason in {line:?}"))
    }
}

#[test]
fn every_mutation_validates_cleanly_or_is_refused_with_a_position_key_and_reason() {
    let seed: u64 = std::env::var("NIMBUS_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(13);
    eprintln!("config fuzz seed {seed} (replay with NIMBUS_TEST_SEED={seed})");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let dir = tempfile::tempdir().unwrap();
    let mut total = 0;
    let mut ok_small: Vec<(PathBuf, String)> = Vec::new();
    let mut ok_total = 0;
    for base in shipped() {
        let yaml = std::fs::read_to_string(&base).unwrap();
        let parsed: Value = serde_saphyr::from_str(&yaml).unwrap();
        let mut keys = Vec::new();
        leaves(&parsed, "", "", &mut keys);
        let stem = base.file_stem().unwrap().to_string_lossy().to_string();
        let mut files: Vec<(PathBuf, String)> = Vec::new();
        for (ptr, key) in &keys {
            let original = parsed.pointer(ptr).unwrap().clone();
            for (i, m) in mutants(&original, &mut rng).into_iter().enumerate() {
                let mut v = parsed.clone();
                set_ptr(&mut v, ptr, m);
                let p = dir.path().join(format!("{stem}-{}-{i}.yaml", files.len()));
                std::fs::write(&p, to_text(&v)).unwrap();
                files.push((p, key.clone()));
            }
        }
        total += files.len();
        let o = nimbus()
            .arg("validate")
            .args(files.iter().map(|(p, _)| p))
            .output()
            .unwrap();
        let (out, err) = (
            String::from_utf8_lossy(&o.stdout).to_string(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        );
        assert!(matches!(o.status.code(), Some(0) | Some(2)), "{}", text(&o));
        assert!(!err.contains("panicked"), "{err}");
        for (p, key) in &files {
            let name = p.display().to_string();
            let prefix = format!("{name}:");
            let oks: Vec<&str> = out.lines().filter(|l| l.starts_with(&prefix)).collect();
            let errs: Vec<&str> = err.lines().filter(|l| l.starts_with(&prefix)).collect();
            assert_eq!(
                oks.len() + errs.len(),
                1,
                "{key}: {}\n{oks:?}\n{errs:?}",
                std::fs::read_to_string(p).unwrap()
            );
            if let Some(e) = errs.first() {
                check_line(&name, e).unwrap_or_else(|why| panic!("{key}: {why}"));
            } else {
                ok_total += 1;
                let line = oks[0];
                let particles: u64 = line
                    .split(" particles")
                    .next()
                    .and_then(|s| s.rsplit(' ').next())
                    .and_then(|n| n.parse().ok())
                    .unwrap_or(u64::MAX);
                if particles <= 30_000 {
                    ok_small.push((p.clone(), key.clone()));
                }
            }
        }
    }
    // One frame of a seeded sample of the small shots that validated.
    let small = ok_small.len();
    // 30 one-frame runs keep CI under a minute; NIMBUS_FUZZ_RUNS=N runs more.
    let runs = std::env::var("NIMBUS_FUZZ_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(30usize)
        .min(small);
    for _ in 0..runs {
        let (p, key) = ok_small.swap_remove(rng.random_range(0..ok_small.len()));
        let out = dir
            .path()
            .join(format!("run-{}", p.file_stem().unwrap().to_string_lossy()));
        let o = nimbus()
            .arg("run")
            .arg(&p)
            .arg("--out")
            .arg(&out)
            .args([
                "--set",
                "output.frames.end=0",
                "--set",
                "output.frames.start=0",
            ])
            .args([
                "--set",
                "output.preview.enabled=false",
                "--log-format",
                "json",
            ])
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{key}: validate said ok, run failed: {}\n{}",
            text(&o),
            std::fs::read_to_string(&p).unwrap()
        );
    }
    eprintln!(
        "config fuzz: {total} mutations validated ({ok_total} ok, {small} of them small enough \
         to simulate), {runs} run for one frame"
    );
}
