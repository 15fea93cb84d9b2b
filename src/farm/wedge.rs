//! Wedges: `--wedge key=v1,v2,...` options, their combinations, each one's run-directory name,
//! and their validation through the config module (every combination loads as a shot, or the
//! farm is refused before anything is submitted).
use crate::config;
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Most combinations one farm may have (each is a simulation job).
pub const MAX_WEDGES: usize = 1000;

/// One `--wedge key=v1,v2,...` option.
#[derive(Debug, Clone, PartialEq)]
pub struct WedgeAxis {
    pub key: String,
    pub values: Vec<String>,
}

/// One combination: a value per axis, in the order the options were given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Wedge {
    pub index: usize,
    /// `<shot>_w<index>` plus a readable suffix of the values, e.g. `tiny_w1_heat_source-0.3`.
    pub name: String,
    /// (key, value) pairs, passed to `nimbus run` as `--set key=value`.
    pub values: Vec<(String, String)>,
    /// The run directory, relative to the farm directory (`runs/<name>`).
    #[serde(default)]
    pub run_dir: String,
    /// What the wedge's simulation task runs first (`nimbus resume RUN` after an interruption).
    #[serde(default)]
    pub command: String,
}

impl Wedge {
    pub fn sets(&self) -> Vec<String> {
        self.values
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect()
    }

    /// `key=value, key=value` (the contact sheet's and status's label).
    pub fn label(&self) -> String {
        if self.values.is_empty() {
            return "(no wedge values)".into();
        }
        self.sets().join(", ")
    }
}

/// Parses `key=v1,v2,...`. Values are split at top-level commas, so a list value keeps its
/// brackets: `--wedge output.preview.sun_direction=[1,1,0],[0,1,0]`.
pub fn parse_axis(arg: &str) -> Result<WedgeAxis> {
    let bad = |why: &str| Error::InvalidInput(format!("--wedge {arg:?}: {why}"));
    let Some((key, list)) = arg.split_once('=') else {
        return Err(bad(
            "expected KEY.PATH=V1,V2,... (e.g. --wedge physics.heat_source=0.2,0.3)",
        ));
    };
    let key = key.trim();
    if key.is_empty() {
        return Err(bad("the key is empty"));
    }
    let mut values = Vec::new();
    let (mut depth, mut cur) = (0i32, String::new());
    for c in list.chars() {
        match c {
            '[' | '{' => depth += 1,
            ']' | '}' => depth -= 1,
            _ => {}
        }
        if c == ',' && depth == 0 {
            values.push(std::mem::take(&mut cur));
        } else {
            cur.push(c);
        }
    }
    values.push(cur);
    let values: Vec<String> = values.into_iter().map(|v| v.trim().to_string()).collect();
    if let Some(i) = values.iter().position(|v| v.is_empty()) {
        return Err(bad(&format!("value {} is empty", i + 1)));
    }
    for (i, v) in values.iter().enumerate() {
        if values[..i].contains(v) {
            return Err(bad(&format!("the value {v:?} is given twice")));
        }
    }
    Ok(WedgeAxis {
        key: key.to_string(),
        values,
    })
}

/// Every combination of the axes (the first axis varies slowest), named after `shot`.
pub fn combinations(shot: &str, axes: &[WedgeAxis]) -> Result<Vec<Wedge>> {
    for (i, a) in axes.iter().enumerate() {
        if axes[..i].iter().any(|b| b.key == a.key) {
            return Err(Error::InvalidInput(format!(
                "--wedge {}: the key is wedged twice (give all its values in one --wedge)",
                a.key
            )));
        }
    }
    let count = axes
        .iter()
        .try_fold(1usize, |n, a| n.checked_mul(a.values.len()))
        .filter(|&n| n <= MAX_WEDGES)
        .ok_or_else(|| {
            Error::InvalidInput(format!(
                "the wedges make more than {MAX_WEDGES} combinations; split the farm"
            ))
        })?;
    let mut out = Vec::with_capacity(count);
    for index in 0..count {
        let mut rest = index;
        let mut values = vec![(String::new(), String::new()); axes.len()];
        for (slot, a) in values.iter_mut().zip(axes).rev() {
            *slot = (a.key.clone(), a.values[rest % a.values.len()].clone());
            rest /= a.values.len();
        }
        let name = wedge_name(shot, index, &values);
        out.push(Wedge {
            index,
            run_dir: format!("runs/{name}"),
            name,
            values,
            command: String::new(),
        });
    }
    Ok(out)
}

/// `<shot>_w<index>_<last key segment>-<value>...`, kept to file-name-safe characters.
fn wedge_name(shot: &str, index: usize, values: &[(String, String)]) -> String {
    let mut name = format!("{}_w{index}", safe(shot));
    for (k, v) in values {
        let last = k.rsplit('.').next().unwrap_or(k);
        name.push('_');
        name.push_str(&safe(&format!("{last}-{v}")));
    }
    // Long suffixes are cut; the index alone keeps names unique.
    name.chars().take(120).collect()
}

fn safe(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars() {
        if c.is_ascii_alphanumeric() || "._-".contains(c) {
            out.push(c);
        } else if !out.ends_with('+') {
            out.push('+');
        }
    }
    out.trim_matches('+').to_string()
}

/// Loads the config once per wedge with its values as `--set` overrides: the first combination
/// that does not validate is the error, named by the wedge key, value and the key's line in the
/// config when the file sets it.
pub fn validate_all(config: &Path, wedges: &[Wedge]) -> Result<()> {
    let file = config.display().to_string();
    let text = std::fs::read_to_string(config).unwrap_or_default();
    for w in wedges {
        let sets = w.sets();
        let Err(e) = crate::shot::load(config, &sets) else {
            continue;
        };
        let Error::Config(msg) = &e else {
            return Err(e);
        };
        // The config module names the override as `FILE: --set KEY: why`; say `--wedge` and
        // point at the key's line when the file sets it.
        for (k, v) in &w.values {
            let Some(why) = msg.strip_prefix(&format!("{file}: --set {k}: ")) else {
                continue;
            };
            return Err(Error::Config(match config::key_position(&text, k) {
                Some((line, col)) => {
                    format!(
                        "{file}:{line}:{col}: {k}: --wedge value {v:?} (wedge {}): {why}",
                        w.name
                    )
                }
                None => format!("{file}: --wedge {k}: value {v:?} (wedge {}): {why}", w.name),
            }));
        }
        return Err(Error::Config(format!(
            "{msg} (with the wedge values {} of wedge {})",
            w.label(),
            w.name
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_split_at_top_level_commas() {
        let a = parse_axis("physics.heat_source=0.2, 0.3").unwrap();
        assert_eq!(a.key, "physics.heat_source");
        assert_eq!(a.values, ["0.2", "0.3"]);
        let b = parse_axis("output.preview.sun_direction=[1,1,0],[0,1,0]").unwrap();
        assert_eq!(b.values, ["[1,1,0]", "[0,1,0]"]);
        assert!(parse_axis("seed").is_err());
        assert!(parse_axis("seed=1,,2").is_err());
        assert!(parse_axis("seed=1,1").is_err());
        assert!(parse_axis("=1").is_err());
    }

    #[test]
    fn combinations_multiply_and_are_named() {
        let axes = [
            parse_axis("seed=1,2").unwrap(),
            parse_axis("physics.heat_source=0.2,0.3,0.4").unwrap(),
        ];
        let w = combinations("tiny", &axes).unwrap();
        assert_eq!(w.len(), 6);
        assert_eq!(w[0].name, "tiny_w0_seed-1_heat_source-0.2");
        assert_eq!(w[5].name, "tiny_w5_seed-2_heat_source-0.4");
        assert_eq!(w[4].sets(), ["seed=2", "physics.heat_source=0.3"]);
        let none = combinations("tiny", &[]).unwrap();
        assert_eq!(none.len(), 1);
        assert_eq!(none[0].name, "tiny_w0");
        assert!(combinations("t", &[axes[0].clone(), axes[0].clone()]).is_err());
    }

    #[test]
    fn names_are_file_safe() {
        let w = combinations("my shot", &[parse_axis("a.b=[1, 2]").unwrap()]).unwrap();
        assert_eq!(w[0].name, "my+shot_w0_b-+1+2");
    }
}
