//! Config hashes. `sim_hash` covers only the keys that change simulated particles, so that a
//! run can be resumed or extended (more frames, other exports) but never continued with other
//! physics. The serialisation is our own canonical JSON (sorted keys, serde_json numbers) so the
//! hash does not depend on key order in the file or on serde_json feature flags.
use super::schema::ShotConfig;
use serde_json::Value;
use sha2::{Digest, Sha256};

/// Keys (dotted paths; a prefix covers its subtree) that do NOT affect the simulation.
pub const NON_SIM_KEYS: &[&str] = &[
    "output.dir",
    "output.preview",
    "output.fps",
    "output.frame_padding",
    "output.frames.end",
    "export",
    "checkpoint",
    "gpu.adapter",
];

/// Bumped when the meaning of the serialisation changes, so old hashes stop matching.
const SIM_TAG: &str = "nimbus-sim-config-v1\n";
const FULL_TAG: &str = "nimbus-full-config-v1\n";

fn to_value(c: &ShotConfig) -> Value {
    // Serialising plain structs of numbers, strings and maps into a Value cannot fail; should
    // it ever, Null still hashes deterministically.
    serde_json::to_value(c).unwrap_or(Value::Null)
}

fn remove(v: &mut Value, path: &str) {
    let mut parts = path.split('.').peekable();
    let mut cur = v;
    while let Some(p) = parts.next() {
        let Value::Object(map) = cur else { return };
        if parts.peek().is_none() {
            map.remove(p);
            return;
        }
        match map.get_mut(p) {
            Some(next) => cur = next,
            None => return,
        }
    }
}

fn sim_value(c: &ShotConfig) -> Value {
    let mut v = to_value(c);
    for k in NON_SIM_KEYS {
        remove(&mut v, k);
    }
    v
}

/// Sorted-key JSON without whitespace.
fn canonical(v: &Value, out: &mut String) {
    match v {
        Value::Object(m) => {
            let mut keys: Vec<&String> = m.keys().collect();
            keys.sort();
            out.push('{');
            for (i, k) in keys.into_iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                out.push_str(&Value::String(k.clone()).to_string());
                out.push(':');
                canonical(&m[k], out);
            }
            out.push('}');
        }
        Value::Array(a) => {
            out.push('[');
            for (i, x) in a.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                canonical(x, out);
            }
            out.push(']');
        }
        other => out.push_str(&other.to_string()),
    }
}

fn hex_sha256(tag: &str, v: &Value) -> String {
    let mut s = String::from(tag);
    canonical(v, &mut s);
    Sha256::digest(s.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Hex SHA-256 of the simulation-affecting keys (all keys except [`NON_SIM_KEYS`]).
pub fn sim_hash(c: &ShotConfig) -> String {
    hex_sha256(SIM_TAG, &sim_value(c))
}

/// Hex SHA-256 of the whole resolved config.
pub fn full_hash(c: &ShotConfig) -> String {
    hex_sha256(FULL_TAG, &to_value(c))
}

/// Dotted paths of simulation-affecting keys whose values differ (lists compare as a whole).
pub fn sim_key_diff(a: &ShotConfig, b: &ShotConfig) -> Vec<String> {
    let mut out = Vec::new();
    diff(&sim_value(a), &sim_value(b), "", &mut out);
    out
}

fn diff(a: &Value, b: &Value, path: &str, out: &mut Vec<String>) {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => diff(u, v, &p, out),
                    _ => out.push(p),
                }
            }
        }
        _ if a != b => out.push(path.to_string()),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(extra: &[&str]) -> ShotConfig {
        let sets: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        super::super::read_str(
            "shot: t\noutput: {frames: {start: 1, end: 10}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
            "t.yaml",
            &sets,
        )
        .unwrap().config
    }

    #[test]
    fn hashes_are_hex_sha256() {
        let h = sim_hash(&cfg(&[]));
        assert_eq!(h.len(), 64);
        assert!(h.chars().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(h, full_hash(&cfg(&[])));
    }

    #[test]
    fn non_sim_keys_do_not_change_sim_hash() {
        let a = cfg(&[]);
        for set in [
            "output.dir=elsewhere",
            "output.frames.end=500",
            "output.fps=30",
            "output.frame_padding=6",
            "output.preview.enabled=true",
            "export.voxel_size=4",
            "export.vdb.compression=zip",
            "checkpoint.every=2",
            "gpu.adapter=nvidia",
        ] {
            let b = cfg(&[set]);
            assert_eq!(sim_hash(&a), sim_hash(&b), "{set}");
            assert_ne!(full_hash(&a), full_hash(&b), "{set}");
            assert!(sim_key_diff(&a, &b).is_empty(), "{set}");
        }
    }

    #[test]
    fn source_overlay_is_output_only_and_absent_when_off() {
        let src = "physics.sources=[{shape: disc, center: [50, 50], radius: 20, strength: 0.1}]";
        let (a, b) = (
            cfg(&[src]),
            cfg(&[src, "output.preview.source_overlay=true"]),
        );
        assert_eq!(sim_hash(&a), sim_hash(&b));
        assert_ne!(full_hash(&a), full_hash(&b));
        // off, the key is not serialised: the hashes of shots from before it are unchanged
        assert!(!canonical_string(&a).contains("source_overlay"));
        assert!(canonical_string(&b).contains("\"source_overlay\":true"));
    }

    fn canonical_string(c: &ShotConfig) -> String {
        let mut s = String::new();
        canonical(&to_value(c), &mut s);
        s
    }

    #[test]
    fn sim_keys_change_sim_hash_and_are_listed() {
        let a = cfg(&[]);
        for (set, key) in [
            ("seed=7", "seed"),
            ("output.frames.start=2", "output.frames.start"),
            ("output.substeps=3", "output.substeps"),
            ("domain.size=[100,60,100]", "domain.size"),
            ("solver.iterations=5", "solver.iterations"),
            ("physics.smoothing.kappa=0.2", "physics.smoothing.kappa"),
            ("adaptive.enabled=true", "adaptive.enabled"),
            ("gpu.backend=vulkan", "gpu.backend"),
        ] {
            let b = cfg(&[set]);
            assert_ne!(sim_hash(&a), sim_hash(&b), "{set}");
            assert_eq!(sim_key_diff(&a, &b), vec![key.to_string()], "{set}");
        }
        let b = cfg(&["seed=7", "solver.gravity=9.8"]);
        assert_eq!(sim_key_diff(&a, &b), vec!["seed", "solver.gravity"]);
    }

    #[test]
    fn free_slip_is_a_sim_key_absent_when_off() {
        let (a, b) = (cfg(&[]), cfg(&["domain.free_slip=true"]));
        assert_ne!(sim_hash(&a), sim_hash(&b));
        assert_eq!(sim_key_diff(&a, &b), vec!["domain.free_slip"]);
        assert!(!canonical_string(&a).contains("free_slip"));
        assert!(canonical_string(&b).contains("\"free_slip\":true"));
    }

    #[test]
    fn min_iterations_is_a_sim_key_absent_at_one() {
        let (a, b) = (
            cfg(&["solver.iterations=4"]),
            cfg(&["solver.iterations=4", "solver.min_iterations=2"]),
        );
        assert_ne!(sim_hash(&a), sim_hash(&b));
        assert_eq!(sim_key_diff(&a, &b), vec!["solver.min_iterations"]);
        // at 1 the key is not serialised: the hashes of shots from before it are unchanged
        assert!(!canonical_string(&a).contains("min_iterations"));
        assert!(canonical_string(&b).contains("\"min_iterations\":2"));
    }

    #[test]
    fn hash_ignores_key_order_in_the_file() {
        let a = super::super::read_str(
            "shot: t\nseed: 3\noutput: {frames: {start: 1, end: 10}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
            "a.yaml",
            &[],
        )
        .unwrap().config;
        let b = super::super::read_str(
            "domain: {spacing: 5, size: [100, 50, 100]}\noutput: {frames: {end: 10, start: 1}}\nseed: 3\nshot: t\n",
            "b.yaml",
            &[],
        )
        .unwrap().config;
        assert_eq!(full_hash(&a), full_hash(&b));
        assert_eq!(sim_hash(&a), sim_hash(&b));
    }

    #[test]
    fn canonical_form_sorts_keys() {
        let v: Value = serde_json::from_str(r#"{"b":1,"a":{"d":[1,2.5],"c":"x"}}"#).unwrap();
        let mut s = String::new();
        canonical(&v, &mut s);
        assert_eq!(s, r#"{"a":{"c":"x","d":[1,2.5]},"b":1}"#);
    }
}
