/// A decoded heat map (`physics.sources` with `shape: image`): `values[j * width + i]` for
/// column i (x) and row j (z), each in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct HeatMap {
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
    /// SHA-256 (hex) of the file's bytes.
    pub sha256: String,
}
