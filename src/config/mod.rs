//! Shot configs: schema, loading with precise errors, `--set` overrides, validation, hashing.
mod schema;
pub use schema::*;

use crate::error::{Error, Result};
use std::path::Path;

/// Loads a shot config, applies `--set key.path=value` overrides, validates it.
pub fn load(path: &Path, overrides: &[String]) -> Result<ShotConfig> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::Config(format!("{}: {e}", path.display())))?;
    if !overrides.is_empty() {
        return Err(Error::Config("--set is not supported yet".into()));
    }
    serde_saphyr::from_str(&text).map_err(|e| Error::Config(format!("{}: {e}", path.display())))
}
