//! The house's layering rules (docs/ARCHITECTURE.md "Layers"), read from the sources: which
//! module of the crate each production file names (`crate::x`, `super::` out of its folder).
//! Test modules (`#[cfg(test)] mod ... { }`) and comments are left out: tests may reach across.
//!
//! Rules not yet met are listed in `KNOWN`, each with the file and the module it names; the test
//! fails on a break that is not listed and on a listed one that has gone (strike it off), so the
//! list is always the true remainder.
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// (rule, file, module named): breaks that remain, to be removed as the house is mended.
const KNOWN: &[(&str, &str, &str)] = &[];

/// Every .rs file under `dir`.
fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The text of `src` without comments and without `#[cfg(test)]` items (a `mod` with braces).
fn production_code(src: &str) -> String {
    let mut out = String::new();
    let mut lines = src.lines().peekable();
    while let Some(line) = lines.next() {
        let t = line.trim_start();
        if t == "#[cfg(test)]" {
            // skip the item that follows: to the brace that closes its first one
            let mut depth = 0i32;
            let mut opened = false;
            for l in lines.by_ref() {
                let code = l.split("//").next().unwrap_or("");
                depth += code.matches('{').count() as i32 - code.matches('}').count() as i32;
                opened |= code.contains('{');
                if (opened && depth <= 0) || (!opened && code.trim_end().ends_with(';')) {
                    break;
                }
            }
            continue;
        }
        let code = match line.find("//") {
            // a `//` inside a string literal (a URL) would cut the line: none of the paths
            // this test looks for follow one on the same line
            Some(i) => &line[..i],
            None => line,
        };
        out.push_str(code);
        out.push('\n');
    }
    out
}

/// The crate's top-level modules named by `code` (a file of module `own`): `crate::x`.
fn named_modules(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue; // e.g. `nimbus_crate::`
        }
        let name: String = rest
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        if !name.is_empty() {
            out.insert(name);
        }
    }
    out
}

/// The top-level module a file under src/ belongs to (`src/sim/pbf.rs` -> `sim`).
fn module_of(rel: &str) -> String {
    let p = rel.trim_start_matches("src/");
    let first = p.split('/').next().unwrap_or(p);
    first.trim_end_matches(".rs").to_string()
}

fn breaks() -> BTreeSet<(String, String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    sources(&root.join("src"), &mut files);
    assert!(files.len() > 50, "src/ holds the crate");
    let mut found = BTreeSet::new();
    for f in files {
        let rel = f
            .strip_prefix(root)
            .expect("under the crate")
            .to_string_lossy()
            .replace('\\', "/");
        let code = production_code(&std::fs::read_to_string(&f).expect("source file"));
        let module = module_of(&rel);
        let named = named_modules(&code);
        let mut broke = |rule: &str, other: &str| {
            found.insert((rule.to_string(), rel.clone(), other.to_string()));
        };
        for other in &named {
            if *other == module {
                continue;
            }
            match module.as_str() {
                "config"
                    if ["sim", "splat", "preview", "io", "pipeline"].contains(&other.as_str()) =>
                {
                    broke(&format!("config imports no {other}"), other)
                }
                "ground" => broke("the ground module imports no other module", other),
                "io" | "splat" | "preview" if other == "sim" => {
                    broke("io, splat and preview import no sim", other)
                }
                "sim" if other == "io" || other == "pipeline" => {
                    broke(&format!("sim imports no {other}"), other)
                }
                "gpu" if other == "config" => broke("gpu imports no config", other),
                _ => {}
            }
        }
        // the f64 mirrors are for the tests: production code outside them never calls them
        let calls_mirror = code.lines().any(|l| {
            l.contains("sim::reference::") || (module == "sim" && l.contains(" reference::"))
        });
        if !rel.starts_with("src/sim/reference/") && calls_mirror {
            broke(
                "production code imports no reference mirror",
                "sim::reference",
            );
        }
    }
    found
}

#[test]
fn the_layering_rules_hold_but_for_the_known_breaks() {
    let found = breaks();
    let known: BTreeSet<(String, String, String)> = KNOWN
        .iter()
        .map(|(r, f, m)| (r.to_string(), f.to_string(), m.to_string()))
        .collect();
    let new: Vec<_> = found.difference(&known).collect();
    let gone: Vec<_> = known.difference(&found).collect();
    assert!(
        new.is_empty(),
        "layering rules broken (docs/ARCHITECTURE.md \"Layers\"): {new:#?}"
    );
    assert!(
        gone.is_empty(),
        "mended, so strike them off KNOWN in tests/layering.rs: {gone:#?}"
    );
}

/// The reader itself: a test module and comments are not production imports; a path is.
#[test]
fn the_reader_sees_paths_and_skips_tests_and_comments() {
    let src = "use crate::ground::ParticleState;\n// crate::sim in a comment\n\
               fn f() { crate::io::x(); }\n#[cfg(test)]\nmod tests {\n    use crate::sim::y;\n    \
               fn g() { if true { crate::pipeline::z(); } }\n}\nfn h() { crate::gpu::w(); }\n";
    let named = named_modules(&production_code(src));
    let want: BTreeSet<String> = ["ground", "io", "gpu"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert_eq!(named, want);
    assert_eq!(module_of("src/sim/pbf.rs"), "sim");
    assert_eq!(module_of("src/fault.rs"), "fault");
}
