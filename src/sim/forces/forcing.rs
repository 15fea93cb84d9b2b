//! `physics.forcing`: the large-scale forcing of an atmospheric case (the GCSS BOMEX case and
//! the like), in physical units, a force of its own (`sim::forces`).
//!
//! Per particle, once a frame, before the frame's first substep moves anything
//! (shaders/forcing.wgsl `apply_forcing`; f64 mirror `sim::reference::forcing`):
//! `T += dt (R(y) - w_ls(y) dS/dz)` and `v = max(v + dt (M(y) - w_ls(y) dQ/dz), 0)`, plus
//! `dt F_h / d` and `dt F_q / d` below the surface layer's depth `d`, where
//! - `R` is the radiative heating and `M` the moisture tendency of `physics.forcing.profile`;
//! - `w_ls` is the large-scale vertical velocity: subsidence advects the horizontal means, not
//!   the particles, so it is the tendency `-w_ls d<.>/dz` of the mean profiles of the liquid
//!   water static temperature `s_l = T + Gamma_d y - Q w` (what eqs. 7 and 11 keep) and of the
//!   total water `q_t = v + w`, measured from the frame-start state on layers of at least one
//!   kernel radius;
//! - `F_h` (K m/s) and `F_q` (kg/kg m/s) are the kinematic surface fluxes, spread over the
//!   particles below `d` (`surface_layer`, default the kernel radius) at the frame's start,
//!   scaled by rho0 A d over their mass (`sim::forces::surface_layer_factor`), so that they put
//!   in rho0 A F per second however many particles the floor's layering holds below `d`.
//!
//! The host builds the layer table and `dt` = the frame's length into the uniform; the step is
//! one per frame because a per-substep increment of a radiative 2 K/day is about one f32 ulp of
//! 300 K. It runs before the frame's first substep, on exactly the state read back at the end
//! of the frame before, so the host knows what it put in: the budget figures of stats.jsonl are
//! `forcing_heat_mean` (K), the mass-weighted mean of the dT it applied, to set against the
//! rise of `static_energy_mean` (the mean s_l), and `forcing_water` (kg), the sum of m dv, to
//! set against the rise of `total_water` (docs/PHYSICS.md "Forcing").
use crate::config::{ForcingConfig, ForcingLevel, ShotConfig};
use crate::error::Result;
use crate::gpu::program::entry_points;
use crate::ground::ParticleState;
use crate::sim::forces::pass::{record_once_a_frame, ParticlePass};
use crate::sim::forces::relative_mass;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};

entry_points! {
    /// The entry point of shaders/forcing.wgsl.
    pub enum ForcingEntry in "forcing.wgsl" {
        /// One frame's forcing, per particle.
        Apply = "apply_forcing",
    }
}

/// Most layers of the table (`layers` of shaders/forcing.wgsl, through the prelude).
pub use crate::ground::limits::MAX_FORCING_LAYERS;

/// Seconds in a day (the profile's radiation is in K/day, its moisture in g/kg per day).
const DAY: f64 = 86_400.0;

/// Uniform of shaders/forcing.wgsl (same layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ForcingParams {
    /// The frame's length (s).
    pub dt: f32,
    pub n_layers: u32,
    pub layer_height: f32,
    pub surface_layer: f32,
    /// Surface fluxes over the surface layer's depth (K/s, kg/kg/s).
    pub surface_heat: f32,
    pub surface_moisture: f32,
    pub _pad: [u32; 2],
    /// (dT/dt K/s, dq/dt kg/kg/s, -, -) at each layer centre.
    pub layers: [[f32; 4]; MAX_FORCING_LAYERS],
}

/// The forcing a frame applies: the layer table (built from the frame-start state) and the
/// surface terms, in f64; [`ForcingTable::params`] is its uniform.
#[derive(Debug, Clone, PartialEq)]
pub struct ForcingTable {
    pub layer_height: f64,
    /// (dT/dt K/s, dq/dt kg/kg/s) at each layer centre.
    pub rates: Vec<[f64; 2]>,
    pub surface_layer: f64,
    /// (K/s, kg/kg/s) below `surface_layer`.
    pub surface: [f64; 2],
}

/// A profile of `physics.forcing.profile` at height y: linear between levels, constant outside.
fn profile_at(levels: &[ForcingLevel], y: f64, field: fn(&ForcingLevel) -> f64) -> f64 {
    crate::config::piecewise_linear(levels, y, |l| l.height, field)
}

impl ForcingTable {
    /// The table of a frame starting from `state`.
    pub fn of_state(cfg: &ShotConfig, f: &ForcingConfig, state: &ParticleState) -> Self {
        let h0 = cfg.domain.kernel_radius();
        let (n, layer_height) = crate::sim::forces::frame_layers(cfg);
        let p = &cfg.physics;
        // mass-weighted layer means of s_l and q_t, each particle shared by the two nearest
        // centres (the weights the shader reads the table back with)
        let (mut s, mut q, mut mass) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for i in 0..state.len() {
            let y = state.pos[i][1] as f64;
            let th = state.thermo[i].map(|v| v as f64);
            let m = relative_mass(state, i);
            let sl = th[0] + p.adiabatic_lapse_rate * y - p.latent_heat * th[2];
            let (k0, k1, t) = crate::sim::thermo::layer_weights(y, layer_height, n);
            for (k, w) in [(k0, 1.0 - t), (k1, t)] {
                s[k] += w * m * sl;
                q[k] += w * m * (th[1] + th[2]);
                mass[k] += w * m;
            }
        }
        let filled: Vec<usize> = (0..n).filter(|&k| mass[k] > 0.0).collect();
        for &k in &filled {
            s[k] /= mass[k];
            q[k] /= mass[k];
        }
        // the vertical gradient at a centre: centred between its filled neighbours, one-sided
        // at the ends; 0 with fewer than two filled layers
        let gradient = |k: usize, m: &[f64]| -> f64 {
            let at = filled.partition_point(|&j| j < k);
            if filled.len() < 2 || filled.get(at) != Some(&k) {
                return 0.0;
            }
            let lo = filled[at.saturating_sub(1)];
            let hi = filled[(at + 1).min(filled.len() - 1)];
            (m[hi] - m[lo]) / ((hi - lo) as f64 * layer_height)
        };
        let rates = (0..n)
            .map(|k| {
                let z = (k as f64 + 0.5) * layer_height;
                let w = profile_at(&f.profile, z, |l| l.subsidence);
                let radiation = profile_at(&f.profile, z, |l| l.radiation) / DAY;
                let moisture = profile_at(&f.profile, z, |l| l.moisture) * 1.0e-3 / DAY;
                [
                    radiation - w * gradient(k, &s),
                    moisture - w * gradient(k, &q),
                ]
            })
            .collect();
        let surface_layer = f.surface_layer.unwrap_or(h0);
        let spread =
            crate::sim::forces::surface_layer_factor(cfg, state, surface_layer) / surface_layer;
        Self {
            layer_height,
            rates,
            surface_layer,
            surface: [
                f.surface_heat_flux * spread,
                f.surface_moisture_flux * spread,
            ],
        }
    }

    /// The uniform of a frame of `seconds`.
    pub fn params(&self, seconds: f64) -> ForcingParams {
        let mut layers = [[0.0f32; 4]; MAX_FORCING_LAYERS];
        for (row, r) in layers.iter_mut().zip(&self.rates) {
            *row = [r[0] as f32, r[1] as f32, 0.0, 0.0];
        }
        ForcingParams {
            dt: seconds as f32,
            n_layers: self.rates.len() as u32,
            layer_height: self.layer_height as f32,
            surface_layer: self.surface_layer as f32,
            surface_heat: self.surface[0] as f32,
            surface_moisture: self.surface[1] as f32,
            _pad: [0; 2],
            layers,
        }
    }

    /// (dT, dv) the frame's forcing gives a particle at height y holding vapor v, as the
    /// uniform holds the table (the vapor floor included).
    fn increments(params: &ForcingParams, y: f64, v: f64) -> [f64; 2] {
        let table = |k: usize| params.layers[k].map(|x| x as f64);
        let n = params.n_layers as usize;
        let t = (y / params.layer_height as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let k0 = t.floor() as usize;
        let k1 = (k0 + 1).min(n - 1);
        let f = t - k0 as f64;
        let mut rate = [0, 1].map(|c| table(k0)[c] + f * (table(k1)[c] - table(k0)[c]));
        if y < params.surface_layer as f64 {
            rate[0] += params.surface_heat as f64;
            rate[1] += params.surface_moisture as f64;
        }
        let dt = params.dt as f64;
        [dt * rate[0], (v + dt * rate[1]).max(0.0) - v]
    }
}

/// What a frame's forcing put in: the mass-weighted mean dT (K) and sum m dv (kg), with m0 the
/// mass of a level-0 particle (kg).
pub fn frame_input(params: &ForcingParams, state: &ParticleState, m0: f64) -> [f64; 2] {
    let (mut mass, mut heat, mut water) = (0.0, 0.0, 0.0);
    for i in 0..state.len() {
        let m = relative_mass(state, i);
        let d = ForcingTable::increments(params, state.pos[i][1] as f64, state.thermo[i][1] as f64);
        mass += m;
        heat += m * d[0];
        water += m * d[1];
    }
    let mean = if mass > 0.0 { heat / mass } else { 0.0 };
    [mean, water * m0]
}

/// The forcing stage: one pass at the start of each frame.
pub struct ForcingStage {
    pass: ParticlePass<ForcingEntry, ForcingParams>,
    cfg: ShotConfig,
    forcing: ForcingConfig,
    /// The uniform of the frame being simulated, and what it puts in (mean K, kg).
    frame: ForcingParams,
    input: [f64; 2],
}

/// The stage, when the shot has `physics.forcing` (its line in `sim::forces::FORCES`).
pub fn stage(setup: &Setup) -> Result<Option<Box<dyn Stage>>> {
    Ok(match setup.shot.config().physics.forcing.is_some() {
        true => Some(Box::new(ForcingStage::from_setup(setup)?)),
        false => None,
    })
}

impl ForcingStage {
    fn m0(&self) -> f64 {
        self.cfg.cell_mass()
    }
}

impl Stage for ForcingStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        let cfg = setup.shot.config().clone();
        let forcing = cfg.physics.forcing.clone().unwrap_or_default();
        let empty = ForcingTable::of_state(&cfg, &forcing, &ParticleState::default());
        let frame = empty.params(cfg.output.frame_seconds);
        Ok(Self {
            pass: ParticlePass::new(setup, ForcingEntry::Apply, "F", "forcing params", &frame)?,
            cfg,
            forcing,
            frame,
            input: [0.0; 2],
        })
    }

    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        record_once_a_frame("forcing", &self.pass, &self.frame, phase, rec, sub)
    }

    fn device_bytes(&self) -> u64 {
        self.pass.device_bytes()
    }

    fn reads_state(&self) -> bool {
        true
    }

    fn start_frame(&mut self, state: &ParticleState) {
        let table = ForcingTable::of_state(&self.cfg, &self.forcing, state);
        self.frame = table.params(self.cfg.output.frame_seconds);
        self.input = frame_input(&self.frame, state, self.m0());
    }

    fn frame_figures(&self, out: &mut Vec<(&'static str, f64)>) {
        out.push(("forcing_heat_mean", self.input[0]));
        out.push(("forcing_water", self.input[1]));
    }
}

#[cfg(feature = "test-hooks")]
impl ForcingStage {
    /// One pass with explicit parameters (the tests share them with the mirror).
    pub fn apply_with(
        &self,
        rec: &mut Recorder,
        live: &crate::gpu::live::LiveBuffer,
        params: &ForcingParams,
    ) -> Result<()> {
        self.pass.record(rec, live, params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(forcing: &str) -> ShotConfig {
        serde_saphyr::from_str(&format!(
            "shot: t\noutput: {{frames: {{start: 1, end: 2}}}}\n\
             domain: {{size: [1000.0, 1000.0, 1000.0], spacing: 50.0}}\n\
             physics: {{forcing: {forcing}}}\n"
        ))
        .unwrap()
    }

    fn state(points: &[(f64, [f64; 3])]) -> ParticleState {
        ParticleState {
            pos: points
                .iter()
                .map(|(y, _)| [0.0, *y as f32, 0.0, 0.0])
                .collect(),
            vel: vec![[0.0; 4]; points.len()],
            thermo: points
                .iter()
                .map(|(_, t)| [t[0] as f32, t[1] as f32, t[2] as f32, 0.0])
                .collect(),
            info: vec![[0, 0]; points.len()],
            density: Vec::new(),
        }
    }

    #[test]
    fn params_layout_matches_wgsl() {
        // 8 scalars, then 64 rows of vec4 (shaders/forcing.wgsl `ForcingParams`)
        assert_eq!(std::mem::size_of::<ForcingParams>(), 32 + 64 * 16);
    }

    #[test]
    fn the_profile_is_linear_between_levels_and_constant_outside() {
        let c = cfg("{profile: [{height: 100, radiation: -2}, {height: 300, radiation: 0}]}");
        let f = c.physics.forcing.unwrap();
        let at = |y| profile_at(&f.profile, y, |l| l.radiation);
        assert_eq!(at(0.0), -2.0);
        assert_eq!(at(200.0), -1.0);
        assert_eq!(at(1000.0), 0.0);
        assert_eq!(profile_at(&[], 5.0, |l| l.radiation), 0.0);
    }

    /// Subsidence of a mean s_l rising 3 K/km at 5 mm/s down warms by 1.5e-5 K/s; of a q_t
    /// falling 2 g/kg per km it dries by 1e-8 /s.
    #[test]
    fn subsidence_is_the_tendency_of_the_mean_profiles() {
        let c = cfg("{profile: [{height: 0, subsidence: -0.005}]}");
        let g = c.physics.adiabatic_lapse_rate;
        // one particle per layer centre (100 m layers: h0 = 100 m)
        let pts: Vec<(f64, [f64; 3])> = (0..10)
            .map(|k| {
                let y = 50.0 + 100.0 * k as f64;
                (y, [300.0 - g * y + 0.003 * y, 0.015 - 2.0e-6 * y, 0.0])
            })
            .collect();
        let t = ForcingTable::of_state(&c, c.physics.forcing.as_ref().unwrap(), &state(&pts));
        assert_eq!(t.rates.len(), 10);
        for r in &t.rates {
            assert!((r[0] - 1.5e-5).abs() < 1e-9, "{r:?}");
            assert!((r[1] + 1.0e-8).abs() < 1e-13, "{r:?}");
        }
    }

    /// The surface flux puts in rho0 A F per second: over a layer that holds rho0 A d every
    /// particle warms by F t / d; with half of them gone the rest take it all.
    #[test]
    fn the_surface_flux_puts_in_the_flux() {
        let c = cfg("{surface_heat_flux: 0.01, surface_moisture_flux: 1.0e-4, surface_layer: 100}");
        let f = c.physics.forcing.as_ref().unwrap();
        // the 1000 x 1000 m floor at 50 m spacing, two layers below 100 m and one above
        let layer = |y: f64| (0..400).map(move |_| (y, [300.0, 0.01, 0.0]));
        let full: Vec<(f64, [f64; 3])> =
            layer(25.0).chain(layer(75.0)).chain(layer(125.0)).collect();
        let thinned: Vec<(f64, [f64; 3])> = layer(25.0).chain(layer(125.0)).collect();
        let m0 = c.cell_mass();
        let seconds = 60.0;
        let rho0 = c.solver.rest_density;
        let expect_water = rho0 * 1000.0 * 1000.0 * 1.0e-4 * seconds;
        for pts in [full, thinned] {
            let s = state(&pts);
            let t = ForcingTable::of_state(&c, f, &s);
            let [heat, water] = frame_input(&t.params(seconds), &s, m0);
            // the mean over every particle: rho0 A d of air (800 particles) warmed by F t / d
            let expect_heat = 0.01 * seconds / 100.0 * 800.0 / pts.len() as f64;
            assert!(
                (heat / expect_heat - 1.0).abs() < 1e-6,
                "{heat} vs {expect_heat}"
            );
            assert!(
                (water / expect_water - 1.0).abs() < 1e-6,
                "{water} vs {expect_water}"
            );
        }
    }

    /// A drying larger than the vapor there takes only the vapor, and the budget says so.
    #[test]
    fn the_vapor_floor_is_in_the_budget() {
        let c = cfg("{profile: [{height: 0, moisture: -1000}]}");
        let f = c.physics.forcing.as_ref().unwrap();
        let s = state(&[(500.0, [290.0, 1.0e-4, 0.0])]);
        let p = ForcingTable::of_state(&c, f, &s).params(60.0);
        let m0 = c.cell_mass();
        let [_, water] = frame_input(&p, &s, m0);
        assert!((water + m0 * 1.0e-4).abs() < 1e-9 * m0, "{water}");
    }
}
