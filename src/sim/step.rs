//! The substep: its stages, their order as the paper gives it (sections 3-5), and the phase
//! each call is timed under. Each call records a stage's passes into the substep's command
//! encoder; nothing here waits for the GPU (except `Timing::HostWaits`, at a phase's end).
use crate::error::Result;
use crate::sim::adaptive::AdaptiveStage;
use crate::sim::forces::OwnForces;
use crate::sim::grid::GridStage;
use crate::sim::pbf::PbfStage;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::smoothing::SmoothingStage;
use crate::sim::stage::{Setup, Stage, Substep};
use crate::sim::thermo::ThermoStage;
use crate::sim::Simulation;

/// The stages of a substep, each bound once to the particle buffers.
pub(super) struct Stages {
    pub pbf: PbfStage,
    pub grid: GridStage,
    pub smoothing: SmoothingStage,
    pub thermo: ThermoStage,
    /// The forces that are stages of their own (`sim::forces`; none in the paper's model).
    pub forces: OwnForces,
    /// Split and merge (paper 5.2); `None` when `adaptive.enabled` is false.
    pub adaptive: Option<AdaptiveStage>,
}

impl Stages {
    pub fn new(setup: &Setup) -> Result<Self> {
        let adaptive = setup.shot.config().adaptive.enabled;
        Ok(Self {
            pbf: PbfStage::from_setup(setup)?,
            grid: GridStage::from_setup(setup)?,
            smoothing: SmoothingStage::from_setup(setup)?,
            thermo: ThermoStage::from_setup(setup)?,
            forces: OwnForces::from_setup(setup)?,
            adaptive: adaptive
                .then(|| AdaptiveStage::from_setup(setup))
                .transpose()?,
        })
    }

    /// One substep, in order: each phase and the stage that records it (none: the shot leaves
    /// the phase out, and it is neither recorded nor timed).
    fn order(&self) -> [(Phase, Option<&dyn Stage>); 10] {
        let adaptive = self.adaptive.as_ref().map(|a| a as &dyn Stage);
        let smoothing = (self.smoothing.iterations() > 0).then_some(&self.smoothing as &dyn Stage);
        let forces = (!self.forces.is_empty()).then_some(&self.forces as &dyn Stage);
        [
            // The forces that are stages of their own, in `sim::forces::FORCES`' order, before
            // the prediction (where PBF takes its external forces), on the state the substep
            // starts from.
            (Phase::Forces, forces),
            // 3. Position Based Fluids: predict (gravity), find neighbours, enforce the
            // density, update v (vorticity confinement, XSPH viscosity).
            (Phase::Predict, Some(&self.pbf)),
            (Phase::Grid, Some(&self.grid)),
            (Phase::Solve, Some(&self.pbf)),
            (Phase::Velocity, Some(&self.pbf)),
            // 4.1 Temperature smoothing (eqs. 12-17), on the neighbourhoods just built.
            (Phase::Smoothing, smoothing),
            // 4. Heating, buoyancy (with the wind and the target pull), adiabatic cooling,
            // phase transition, latent heat (eqs. 5-11).
            (Phase::Cloud, Some(&self.thermo)),
            // 5.2 Adaptive particles: shape energy and marks, merges, splits.
            (Phase::Mark, adaptive),
            (Phase::Merge, adaptive),
            (Phase::Split, adaptive),
        ]
    }

    /// Records one substep, each call timed under its phase.
    fn record(&self, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        for (phase, stage) in self.order() {
            if let Some(stage) = stage {
                rec.begin(phase);
                stage.record(phase, rec, sub)?;
                rec.end_phase()?;
            }
        }
        Ok(())
    }

    /// Bytes of every stage's own device buffers.
    pub fn device_bytes(&self) -> u64 {
        self.pbf.device_bytes()
            + self.grid.device_bytes()
            + self.smoothing.device_bytes()
            + self.thermo.device_bytes()
            + self.forces.device_bytes()
            + self.adaptive.as_ref().map_or(0, |a| a.device_bytes())
    }
}

impl Simulation {
    /// Records one substep of `dt` (`first`: the frame's first).
    pub(super) fn record_substep(&self, rec: &mut Recorder, dt: f64, first: bool) -> Result<()> {
        // the stages take the substep as the PBF parameters hold it (f32), as they always have
        let dt_f32 = self.params.dt as f64;
        debug_assert!((dt_f32 - dt).abs() <= dt * 1e-6);
        let sub = Substep {
            live: &self.b.live,
            dt: dt_f32,
            time: self.clock.time,
            iterations: self.iterations,
            first,
        };
        self.s.record(rec, &sub)
    }
}
