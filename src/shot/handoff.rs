//! The NanoVDB hand-off's grids (`export.nanovdb`), checked against the grids the VDB files
//! hold (`export::vdb_grid_names`): each selected grid must be one of them, once, and only
//! float grids can be quantised. Here rather than in config, which imports no export.
use crate::config::{ExportConfig, Issue, NanoPrecision, MAX_NANOVDB_NAME_BYTES};
use crate::export::vdb_grid_names;

/// The first issue of `export.nanovdb`, if any.
pub fn check(e: &ExportConfig) -> Result<(), Issue> {
    let mut k = Checks::default();
    nanovdb(&mut k, e);
    k.issues.into_iter().next().map_or(Ok(()), Err)
}

#[derive(Default)]
struct Checks {
    issues: Vec<Issue>,
}

impl Checks {
    fn fail(&mut self, keys: &[&str], msg: String) {
        self.issues.push(Issue {
            keys: keys.iter().map(|k| k.to_string()).collect(),
            msg,
        });
    }
}

fn nanovdb(k: &mut Checks, e: &ExportConfig) {
    let n = &e.nanovdb;
    if !n.enabled {
        return;
    }
    let names = vdb_grid_names(e);
    if names.is_empty() {
        k.fail(
            &["export.nanovdb"],
            "every export.grids name is empty, so there is no grid to write; name one or set export.nanovdb: false".into(),
        );
        return;
    }
    let list = names
        .iter()
        .map(|g| g.name.as_str())
        .collect::<Vec<_>>()
        .join(", ");
    let mut seen = std::collections::BTreeSet::new();
    for (i, (name, own)) in n.grids.0.iter().enumerate() {
        let key = match own {
            Some(_) => format!("export.nanovdb.grids.{name}"),
            None => format!("export.nanovdb.grids[{i}]"),
        };
        if !names.iter().any(|g| &g.name == name) {
            k.fail(
                &[key.as_str(), "export.nanovdb.grids"],
                format!("{name:?} is not a grid of the VDB files (they hold: {list})"),
            );
        } else if !seen.insert(name.as_str()) {
            k.fail(
                &[key.as_str(), "export.nanovdb.grids"],
                format!("{name:?} is listed twice"),
            );
        }
    }
    for g in &names {
        let own = n
            .grids
            .0
            .iter()
            .find(|(name, _)| *name == g.name)
            .map(|(_, p)| *p);
        let precision = match own {
            None if !n.grids.0.is_empty() => continue, // not selected
            Some(Some(p)) => p,
            _ => n.precision,
        };
        if g.vector() && precision != NanoPrecision::Float {
            let key = format!("export.nanovdb.grids.{}", g.name);
            let keys: Vec<&str> = match own {
                Some(Some(_)) => vec![key.as_str()],
                _ => vec!["export.nanovdb.precision", "export.nanovdb"],
            };
            k.fail(
                &keys,
                format!(
                    "{} quantises float grids only, and {:?} is a vector grid (NanoVDB stores it as Vec3f and has no quantised vector type): give it its own precision, e.g. export.nanovdb.grids: {{density: {}, {}: float}}, or leave it out of export.nanovdb.grids",
                    precision.name(),
                    g.name,
                    precision.name(),
                    g.name
                ),
            );
        }
        if g.name.len() > MAX_NANOVDB_NAME_BYTES {
            k.fail(
                &["export.nanovdb.grids"],
                format!(
                    "grid name {:?} is longer than NanoVDB's {} bytes",
                    g.name, MAX_NANOVDB_NAME_BYTES
                ),
            );
        }
    }
}
