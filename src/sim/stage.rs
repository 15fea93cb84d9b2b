//! `Stage`: one physical step of the substep (PBF, the neighbour grid, smoothing, the
//! thermodynamics, a force of its own, split and merge). A stage is built once from the
//! prepared shot and the particle buffers ([`Setup`]), records its compute passes into the
//! substep's command encoder, and reports the device bytes it allocated. Which stages run, in
//! which order, and the phase each call is timed under are `sim::step`'s.
//!
//! A stage runs one or more `gpu::program::Program`s (a program is one WGSL file and its entry
//! points); "stage" names nothing else.
use crate::error::Result;
use crate::gpu::live::LiveBuffer;
use crate::gpu::Context;
use crate::ground::ParticleState;
use crate::shot::Shot;
use crate::sim::buffers::ParticleBuffers;
use crate::sim::grid_params::GridParams;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::sources::HeatMaps;

/// What a stage is built from: the device, the prepared shot, the particle buffers and what
/// the simulation derived from the shot for them.
pub struct Setup<'a> {
    pub ctx: &'a Context,
    pub shot: &'a Shot,
    pub buffers: &'a ParticleBuffers,
    /// The neighbour grid (host copy, with the walls' particle count).
    pub grid: &'a GridParams,
    /// The heat maps of the image sources, with room for the target controller's supply.
    pub maps: &'a HeatMaps,
}

/// What one substep gives every stage.
pub struct Substep<'a> {
    /// The live count and dispatch arguments, on the GPU.
    pub live: &'a LiveBuffer,
    /// The substep's length (s), as the PBF parameters hold it (f32).
    pub dt: f64,
    /// Simulated time at the substep's start (s).
    pub time: f64,
    /// Density iterations of this substep.
    pub iterations: u32,
    /// Whether this is the frame's first substep.
    pub first: bool,
}

/// One physical step of the substep.
pub trait Stage {
    /// The stage of a shot, bound once to the particle buffers.
    fn from_setup(setup: &Setup) -> Result<Self>
    where
        Self: Sized;

    /// Records the stage's passes of `phase` (one of the phases `sim::step` times it under)
    /// for one substep. Nothing here waits for the GPU.
    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()>;

    /// Bytes of the device buffers the stage itself allocated (the particle buffers it borrows
    /// are `ParticleBuffers`').
    fn device_bytes(&self) -> u64;

    /// Whether the stage is given the state each frame starts from ([`Stage::start_frame`]);
    /// then every frame reads the whole state back.
    fn reads_state(&self) -> bool {
        false
    }

    /// Before a frame's first substep is recorded, when [`Stage::reads_state`]: the state the
    /// frame starts from (the initial or resumed one, or what the frame before read back), so
    /// that a resumed run sets what the uninterrupted one did.
    fn start_frame(&mut self, _state: &ParticleState) {}

    /// The stage's figures of the frame just simulated (stats.jsonl names).
    fn frame_figures(&self, _out: &mut Vec<(&'static str, f64)>) {}
}

/// The error of a stage asked for a phase it has no passes in (`sim::step` pairs them, so this
/// is a mistake in that list).
pub(crate) fn not_recorded(stage: &str, phase: Phase) -> crate::error::Error {
    crate::error::Error::Runtime(format!("the {stage} stage records no {phase:?} phase"))
}
