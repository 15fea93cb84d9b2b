//! Where a simulation stands in time.

/// Where the simulation stands; checkpoints store it next to the particles.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SimClock {
    pub frame: u32,
    pub step: u64,
    pub time: f64,
    pub next_id: u32,
}
