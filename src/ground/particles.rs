//! The particle set as the host holds it.

/// Host copy of all per-particle state: what checkpoints store and what the splat reads.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ParticleState {
    pub pos: Vec<[f32; 4]>,
    pub vel: Vec<[f32; 4]>,
    /// (temperature, vapor, cloud, shape energy)
    pub thermo: Vec<[f32; 4]>,
    /// (id, level)
    pub info: Vec<[u32; 2]>,
    /// SPH density of the last solve (kg/m^3), used by the splat's m/rho weights.
    pub density: Vec<f32>,
}

impl ParticleState {
    pub fn len(&self) -> usize {
        self.pos.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }
}
