//! `physics.wind.coriolis` and `physics.wind.surface_friction`: the momentum forcing of an
//! atmospheric case, a force of its own (`sim::forces`).
//!
//! Per particle, at the start of every substep (shaders/coriolis.wgsl `apply_coriolis`; f64
//! mirror `sim::reference::coriolis`):
//! - with `coriolis` f, the horizontal velocity's departure a = u_h - U_g(y) from the
//!   geostrophic wind (the profile of `physics.wind`) turns by the angle f dt, the exact
//!   solution of du_h/dt = -f y x a over dt with U_g held (so any number of substeps turns the
//!   same, as the wind's relaxation). With y up, f > 0 turns the air to the right of its motion
//!   seen from above (the northern hemisphere), so north is -z. The thermo stage's relaxation
//!   is off then (`sim::wind::relaxed_rows`): a geostrophic wind is where the pressure gradient
//!   balances the Coriolis force, not a velocity the air is pulled to;
//! - with `surface_friction` u*, the particles below the surface layer's depth d take the
//!   surface stress rho u*^2 spread over their mass (rho0 A d, scaled by
//!   `sim::forces::surface_layer_factor` from the frame-start state as the surface fluxes):
//!   their velocity over the ground (`ground_velocity`, for a shot in a frame moving with the
//!   wind) loses dt u*^2 / d of its speed a substep, never more than it has (the bulk law of
//!   an LES's prescribed u*, per particle).
use crate::config::ShotConfig;
use crate::error::Result;
use crate::gpu::program::entry_points;
use crate::sim::forces::pass::ParticlePass;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};
use crate::sim::wind::MAX_WIND_LEVELS;

entry_points! {
    /// The entry point of shaders/coriolis.wgsl.
    pub enum CoriolisEntry in "coriolis.wgsl" {
        /// One substep's Coriolis turn and surface stress, per particle.
        Apply = "apply_coriolis",
    }
}

/// Uniform of shaders/coriolis.wgsl (same layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CoriolisParams {
    /// cos and sin of the substep's turn f dt.
    pub turn_cos: f32,
    pub turn_sin: f32,
    /// Levels of the geostrophic wind (0: no Coriolis force).
    pub n_levels: u32,
    /// Depth of the layer that takes the surface stress (m).
    pub surface_layer: f32,
    /// The speed the stress takes off in the substep, dt u*^2 / d (m/s).
    pub drag: f32,
    pub _pad: u32,
    /// The ground's velocity in the shot's frame (x, z; m/s).
    pub ground: [f32; 2],
    /// (height m, speed m/s, heading rad, -) by increasing height (`sim::wind::rows`).
    pub levels: [[f32; 4]; MAX_WIND_LEVELS],
}

impl CoriolisParams {
    /// The uniform of a substep of `dt` (s), the stress spread over the air below the surface
    /// layer with `factor` (`sim::forces::surface_layer_factor`: 1 when the particles there hold
    /// rho0 A d); all zeros (nothing acts) without wind.
    pub fn new(cfg: &ShotConfig, dt: f64, factor: f64) -> Self {
        let Some(w) = &cfg.physics.wind else {
            return bytemuck::Zeroable::zeroed();
        };
        let (n_levels, levels) = match w.coriolis {
            Some(_) => crate::sim::wind::rows(cfg),
            None => (0, [[0.0; 4]; MAX_WIND_LEVELS]),
        };
        let turn = w.coriolis.unwrap_or(0.0) * dt;
        let depth = w.surface_layer.unwrap_or(cfg.domain.kernel_radius());
        Self {
            turn_cos: turn.cos() as f32,
            turn_sin: turn.sin() as f32,
            n_levels,
            surface_layer: depth as f32,
            drag: (factor * dt * w.surface_friction * w.surface_friction / depth) as f32,
            _pad: 0,
            ground: w.ground_velocity.map(|g| g as f32),
            levels,
        }
    }
}

/// The Coriolis and surface-stress stage: one pass at the start of each substep.
pub struct CoriolisStage {
    pass: ParticlePass<CoriolisEntry, CoriolisParams>,
    cfg: ShotConfig,
    /// The frame's `surface_layer_factor` (1 without a surface stress).
    factor: f64,
}

/// The stage, when the shot's wind has `coriolis` or `surface_friction` (its line in
/// `sim::forces::FORCES`).
pub fn stage(setup: &Setup) -> Result<Option<Box<dyn Stage>>> {
    let on = (setup.shot.config().physics.wind.as_ref()).is_some_and(|w| w.has_momentum_forcing());
    Ok(match on {
        true => Some(Box::new(CoriolisStage::from_setup(setup)?)),
        false => None,
    })
}

impl Stage for CoriolisStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        let cfg = setup.shot.config().clone();
        let first = CoriolisParams::new(&cfg, 0.0, 1.0);
        Ok(Self {
            pass: ParticlePass::new(setup, CoriolisEntry::Apply, "C", "coriolis params", &first)?,
            cfg,
            factor: 1.0,
        })
    }

    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        match phase {
            Phase::Forces => {
                let params = CoriolisParams::new(&self.cfg, sub.dt, self.factor);
                self.pass.record(rec, sub.live, &params)
            }
            other => Err(crate::sim::stage::not_recorded("coriolis", other)),
        }
    }

    fn device_bytes(&self) -> u64 {
        self.pass.device_bytes()
    }

    /// The stress needs the air below the surface layer at the frame's start.
    fn reads_state(&self) -> bool {
        self.cfg
            .physics
            .wind
            .as_ref()
            .is_some_and(|w| w.surface_friction > 0.0)
    }

    fn start_frame(&mut self, state: &crate::ground::ParticleState) {
        if let Some(w) = &self.cfg.physics.wind {
            let depth = w.surface_layer.unwrap_or(self.cfg.domain.kernel_radius());
            self.factor = crate::sim::forces::surface_layer_factor(&self.cfg, state, depth);
        }
    }
}

#[cfg(feature = "test-hooks")]
impl CoriolisStage {
    /// One pass with explicit parameters (the tests share them with the mirror).
    pub fn apply_with(
        &self,
        rec: &mut Recorder,
        live: &crate::gpu::live::LiveBuffer,
        params: &CoriolisParams,
    ) -> Result<()> {
        self.pass.record(rec, live, params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::reference::coriolis::apply_coriolis;

    fn cfg(wind: &str) -> ShotConfig {
        crate::shot::load_str(
            &format!(
                "shot: t\noutput: {{frames: {{start: 1, end: 2}}}}\n\
                 domain: {{size: [1000, 1000, 1000], spacing: 50, periodic: [x, z]}}\n\
                 physics: {{wind: {wind}}}\n"
            ),
            "t.yaml",
            &[],
        )
        .unwrap()
        .into_config()
    }

    /// Horizontal velocity of one particle at height y after `n` substeps of `dt`.
    fn after(c: &ShotConfig, y: f64, u: [f64; 2], n: usize, dt: f64) -> [f64; 2] {
        let p = CoriolisParams::new(c, dt, 1.0);
        let mut v = [[u[0], 0.0, u[1], 0.0]];
        for _ in 0..n {
            apply_coriolis(&p, &[[0.0, y, 0.0]], &mut v);
        }
        [v[0][0], v[0][2]]
    }

    #[test]
    fn params_layout_matches_wgsl() {
        // 6 scalars and a vec2, then 16 rows of vec4 (shaders/coriolis.wgsl `CoriolisParams`)
        assert_eq!(std::mem::size_of::<CoriolisParams>(), 32 + 16 * 16);
    }

    /// Air at rest under a geostrophic wind U_g along +x oscillates about it: the pressure
    /// gradient first pushes it towards the low pressure, north (-z), and the Coriolis force
    /// turns it to its right, so after a quarter of the inertial period 2 pi / f it moves at
    /// U_g (1, -1) and after half at 2 U_g; the same for 1 substep or 40.
    #[test]
    fn the_inertial_oscillation_is_exact_at_any_substeps() {
        let f = 1.0e-3;
        let c = cfg(&format!(
            "{{coriolis: {f}, profile: [{{height: 0, speed: 10}}]}}"
        ));
        let quarter = std::f64::consts::FRAC_PI_2 / f;
        for n in [1, 40] {
            let u = after(&c, 500.0, [0.0, 0.0], n, quarter / n as f64);
            assert!(
                (u[0] - 10.0).abs() < 1e-4 && (u[1] + 10.0).abs() < 1e-4,
                "{n}: {u:?}"
            );
            let u = after(&c, 500.0, [0.0, 0.0], 2 * n, quarter / n as f64);
            assert!(
                (u[0] - 20.0).abs() < 1e-4 && u[1].abs() < 1e-4,
                "{n}: {u:?}"
            );
        }
        // air at the geostrophic wind stays there: the pressure gradient balances the force
        let u = after(&c, 500.0, [10.0, 0.0], 7, 60.0);
        assert!((u[0] - 10.0).abs() < 1e-5 && u[1].abs() < 1e-5, "{u:?}");
    }

    /// The stress takes dt u*^2 / d off the speed over the ground in the surface layer, along
    /// that velocity, stops at the ground's velocity and leaves the air above alone.
    #[test]
    fn the_surface_stress_slows_the_air_over_the_ground() {
        let c = cfg(
            "{surface_friction: 0.3, surface_layer: 100, ground_velocity: [8, 0], \
             profile: [{height: 0, speed: 0}]}",
        );
        let p = CoriolisParams::new(&c, 10.0, 1.0);
        assert!((p.drag as f64 - 10.0 * 0.09 / 100.0).abs() < 1e-8);
        // 5 m/s over the ground along -x, and 1 along +z (the ground moves at +8 along x)
        let u = after(&c, 50.0, [3.0, 1.0], 1, 10.0);
        let before = [3.0 - 8.0, 1.0];
        let speed = f64::hypot(before[0], before[1]);
        let k = 1.0 - 0.009 / speed;
        assert!((u[0] - (8.0 + k * before[0])).abs() < 1e-5, "{u:?}");
        assert!((u[1] - k * before[1]).abs() < 1e-5, "{u:?}");
        // never past the ground's velocity
        let u = after(&c, 50.0, [8.001, 0.0], 1, 10.0);
        assert!((u[0] - 8.0).abs() < 1e-6 && u[1] == 0.0, "{u:?}");
        // above the layer nothing acts, and without coriolis nothing turns
        assert_eq!(after(&c, 150.0, [3.0, 1.0], 3, 10.0), [3.0, 1.0]);
    }

    /// A column of surface air under a geostrophic wind and the stress settles where the
    /// Coriolis force balances the drag: slower than U_g and turned towards low pressure (to
    /// the left of U_g in the north), as the surface wind of an Ekman layer.
    #[test]
    fn drag_and_coriolis_balance_turned_to_the_left() {
        let c = cfg(
            "{coriolis: 1.0e-4, surface_friction: 0.3, surface_layer: 500, \
             profile: [{height: 0, speed: 10}]}",
        );
        let u = after(&c, 100.0, [10.0, 0.0], 200_000, 30.0);
        // balance: f |u - U_g| = u*^2 / d = 1.8e-4 m/s^2: the departure is 1.8 m/s, at right
        // angles to the surface wind
        let a = [u[0] - 10.0, u[1]];
        let depart = a[0].hypot(a[1]);
        assert!((depart - 1.8).abs() < 0.02, "{u:?}");
        assert!(
            u[1] < 0.0 && u[0] < 10.0,
            "turned to -z, the left of +x: {u:?}"
        );
        assert!((a[0] * u[0] + a[1] * u[1]).abs() < 0.05 * depart * u[0].hypot(u[1]));
    }
}
