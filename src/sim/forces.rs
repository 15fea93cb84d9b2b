//! Every force on the particles, in one list ([`FORCES`]).
//!
//! The paper's forces act inside the stages that hold their inputs, and their WGSL stays there:
//! gravity in the PBF prediction (before p* = x + v dt, where PBF takes its external forces),
//! XSPH viscosity and vorticity confinement in the velocity update (they read the neighbours the
//! solve walked), buoyancy and cloud weight (eq. 6), the wind and the target pull in the
//! thermodynamics (they read the temperature, water and height that pass computes). Moving one
//! into a pass of its own would change the order of float operations, so outputs, and cost a
//! pass over the particles; the list says where each one is.
//!
//! A new force is a stage of its own (`sim::stage::Stage`): its WGSL (`shaders/<force>.wgsl`),
//! its f64 mirror (`sim/reference/<force>.rs`), its module (`sim/forces/<force>.rs`: parameters,
//! a [`pass::ParticlePass`] that runs the WGSL, `Stage` (a once-a-frame force records with
//! [`pass::record_once_a_frame`]), and a `pub fn stage(&Setup) -> Result<Option<Box<dyn Stage>>>` giving
//! `None` when the shot leaves it off), and one line in [`FORCES`],
//! `Force::own("drag", &["physics.drag"], drag::stage),` (with the module's `mod` line).
//! Forces of their own run first in the substep, before the PBF prediction (where PBF takes
//! its external forces), in list order, timed under `Phase::Forces` (stats.jsonl
//! `phase_ms.forces`, absent while none runs).
pub mod coriolis;
pub mod entrainment;
pub mod forcing;
pub mod pass;

use crate::error::Result;
use crate::gpu::program::Entry;
use crate::sim::pbf::PbfEntry;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};
use crate::sim::thermo::ThermoEntry;

/// The factor that spreads a surface flux over the air actually below `depth` at the frame's
/// start: the box's air below it at rest density, rho0 A depth, over the particles' mass there.
/// A flux F divided by `depth` and times this puts rho0 A F a second into the air whatever the
/// particles' layering at the floor (100 m particles hold 7% less than rho0 A d below 100 m in
/// the BOMEX shot, 160 m ones 4-26% more); 0 when no particle is below `depth`.
pub fn surface_layer_factor(
    cfg: &crate::config::ShotConfig,
    state: &crate::ground::ParticleState,
    depth: f64,
) -> f64 {
    let s = &cfg.domain.size;
    let d = cfg.domain.spacing;
    // in level-0 particles (`ShotConfig::cell_mass`)
    let nominal = s[0] * s[2] * depth / (d * d * d);
    let below: f64 = (0..state.len())
        .filter(|&i| (state.pos[i][1] as f64) < depth)
        .map(|i| relative_mass(state, i))
        .sum();
    if below > 0.0 {
        nominal / below
    } else {
        0.0
    }
}

/// Mass of particle i relative to a level-0 particle's (2^-level; a level past the deepest
/// counts as the deepest).
pub(crate) fn relative_mass(state: &crate::ground::ParticleState, i: usize) -> f64 {
    (-(state.info[i][1].min(crate::ground::levels::MAX_LEVEL) as f64)).exp2()
}

/// The horizontal layers of the per-frame tables (forcing, entrainment): as many as fit a
/// kernel radius each into the height, 1 to [`forcing::MAX_FORCING_LAYERS`]; (count, height m).
pub(crate) fn frame_layers(cfg: &crate::config::ShotConfig) -> (usize, f64) {
    let height = cfg.domain.size[1];
    let n = ((height / cfg.domain.kernel_radius()).floor() as usize)
        .clamp(1, forcing::MAX_FORCING_LAYERS);
    (n, height / n as f64)
}

/// A force and where it acts.
pub struct Force {
    pub name: &'static str,
    /// The config keys that set it.
    pub keys: &'static [&'static str],
    pub acts: Acts,
}

impl Force {
    /// A force that is a stage of its own: its line in [`FORCES`].
    pub const fn own(name: &'static str, keys: &'static [&'static str], stage: BuildForce) -> Self {
        Self {
            name,
            keys,
            acts: Acts::Own(stage),
        }
    }
}

/// Where a force acts.
pub enum Acts {
    /// Inside a stage's entry point, which reads it from its parameters (`uniform`, the WGSL
    /// name of the field).
    Within { entry: Site, uniform: &'static str },
    /// A stage of its own, built when the shot turns it on.
    Own(BuildForce),
}

/// Builds a force's stage, or gives `None` when the shot leaves the force off.
pub type BuildForce = fn(&Setup) -> Result<Option<Box<dyn Stage>>>;

/// The entry point a force acts in.
#[derive(Debug, Clone, Copy)]
pub enum Site {
    Pbf(PbfEntry),
    Thermo(ThermoEntry),
}

impl Site {
    /// The WGSL file and the entry point's name.
    pub fn wgsl(self) -> (&'static str, &'static str) {
        match self {
            Site::Pbf(e) => (PbfEntry::SHADER, e.name()),
            Site::Thermo(e) => (ThermoEntry::SHADER, e.name()),
        }
    }
}

/// Every force, in the order it acts in a substep.
pub const FORCES: &[Force] = &[
    Force {
        name: "gravity",
        keys: &["solver.gravity"],
        acts: Acts::Within {
            entry: Site::Pbf(PbfEntry::Predict),
            uniform: "prm.gravity",
        },
    },
    Force {
        name: "XSPH viscosity",
        keys: &["solver.xsph"],
        acts: Acts::Within {
            entry: Site::Pbf(PbfEntry::ViscosityConfine),
            uniform: "prm.xsph",
        },
    },
    Force {
        name: "vorticity confinement",
        keys: &["solver.vorticity"],
        acts: Acts::Within {
            entry: Site::Pbf(PbfEntry::ViscosityConfine),
            uniform: "prm.vorticity",
        },
    },
    Force {
        name: "buoyancy and cloud weight (eq. 6)",
        keys: &[
            "physics.buoyancy",
            "physics.cloud_weight",
            "physics.buoyancy_reference",
        ],
        acts: Acts::Within {
            entry: Site::Thermo(ThermoEntry::Step),
            uniform: "P.buoyancy",
        },
    },
    Force {
        name: "wind",
        keys: &["physics.wind"],
        acts: Acts::Within {
            entry: Site::Thermo(ThermoEntry::Step),
            uniform: "P.wind_fraction",
        },
    },
    Force {
        name: "target pull",
        keys: &["control.target.pull", "control.target.reach"],
        acts: Acts::Within {
            entry: Site::Thermo(ThermoEntry::Step),
            uniform: "P.control_pull",
        },
    },
    // first of the forces of their own: its host table is of the state read back, which the
    // pass must find unchanged for the clear air to take exactly what the clouds give up
    Force::own(
        "entrainment (the clouds mixing with the clear air)",
        &["physics.entrainment"],
        entrainment::stage,
    ),
    Force::own("large-scale forcing", &["physics.forcing"], forcing::stage),
    Force::own(
        "Coriolis force and surface stress",
        &["physics.wind.coriolis", "physics.wind.surface_friction"],
        coriolis::stage,
    ),
];

/// The forces of their own a shot turns on, recorded one after the other.
pub struct OwnForces {
    stages: Vec<Box<dyn Stage>>,
}

impl OwnForces {
    /// Whether the shot has none (then `Phase::Forces` is not recorded at all).
    pub fn is_empty(&self) -> bool {
        self.stages.is_empty()
    }
}

impl Stage for OwnForces {
    /// The forces of [`FORCES`] that are stages of their own and that the shot turns on.
    fn from_setup(setup: &Setup) -> Result<Self> {
        let mut stages = Vec::new();
        for force in FORCES {
            if let Acts::Own(build) = force.acts {
                stages.extend(build(setup)?);
            }
        }
        Ok(Self { stages })
    }

    /// Every force of its own, in list order.
    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        for stage in &self.stages {
            stage.record(phase, rec, sub)?;
        }
        Ok(())
    }

    fn device_bytes(&self) -> u64 {
        self.stages.iter().map(|s| s.device_bytes()).sum()
    }

    fn reads_state(&self) -> bool {
        self.stages.iter().any(|s| s.reads_state())
    }

    fn start_frame(&mut self, state: &crate::ground::ParticleState) {
        for stage in &mut self.stages {
            stage.start_frame(state);
        }
    }

    fn frame_figures(&self, out: &mut Vec<(&'static str, f64)>) {
        for stage in &self.stages {
            stage.frame_figures(out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each force acting inside a stage is read where the list says: its uniform field in the
    /// WGSL file of its entry point, which is there; and every force names its keys.
    #[test]
    fn every_force_is_where_the_list_says() {
        for force in FORCES {
            assert!(!force.keys.is_empty(), "{}", force.name);
            let Acts::Within { entry, uniform } = &force.acts else {
                continue;
            };
            let (shader, name) = entry.wgsl();
            let src = crate::gpu::shaders::source(shader).unwrap();
            assert!(
                src.contains(&format!("fn {name}(")),
                "{}: {name}",
                force.name
            );
            assert!(
                src.contains(uniform),
                "{}: {uniform} in {shader}",
                force.name
            );
        }
    }
}
