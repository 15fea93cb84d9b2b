//! Which adapter to open: the `gpu` section of a shot config, defined beside the code that
//! reads it so that the device layer needs nothing of the config.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GpuConfig {
    /// `auto` or a case-insensitive substring of the adapter name.
    pub adapter: String,
    pub backend: Backend,
}
impl Default for GpuConfig {
    fn default() -> Self {
        Self {
            adapter: "auto".into(),
            backend: Backend::Auto,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    Auto,
    Vulkan,
    Gl,
}
