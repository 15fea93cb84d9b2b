//! Cloud thermodynamics stage (paper section 4): one compute pass per substep, run after the
//! PBF move and the temperature smoothing ([`crate::sim::smoothing`]).
//!
//! Per particle, in the paper's order (shaders/thermo.wgsl, entry `thermo_step`; f64 mirror
//! `sim::reference::thermo::thermo_step`):
//! 1. ground heating, eq. 5: `T += dt Se n(x, z, t)` for particles below `heat_height`, where
//!    `n` in [0, 1] is the hash value noise of [`crate::ground::noise`] over the ground, drifting in
//!    time at `heat_noise_speed` lattice cells per second and stretched by `heat_noise_contrast`;
//!    plus every `physics.sources` entry's heating and vapor ([`crate::sim::sources`]: shapes
//!    on the ground and in the air, heat maps in a storage buffer at binding 4);
//! 2. buoyancy and cloud weight, eq. 6: `u_y += dt (kb (T - T0(y)) / T0(y) - kg w)` with the
//!    environment `T0(y)` of `physics.environment` (with its optional capping inversion), T
//!    read as T (1 + 0.608 v) with `physics.virtual_temperature`; and
//!    the wind, `u_h += f (U(y) - u_h)` with `f = 1 - exp(-dt / tau)` ([`crate::sim::wind`]);
//! 3. adiabatic cooling, eq. 7: `T -= Gamma_d dy` over the height `dy` the substep's move gained
//!    (`vel.w`, written by pbf.wgsl's `update_velocity`);
//! 4. phase transition, eqs. 8-10: `w* = clamp(w + f (v - gamma), 0, v + w)`, `v* = (v + w) - w*`
//!    with `gamma = min(A exp(B / (T + C)), v + w)` and `f = 1 - exp(-alpha dt)` (the exact
//!    solution of the linear relaxation of eq. 9 over one step, so `f` stays below 1 for any dt;
//!    for small `alpha dt` it is `alpha dt`). v + w is conserved per particle up to one float
//!    rounding and neither goes negative;
//! 5. latent heat, eq. 11: `T += Q (w* - w)` (eq. 11 integrated the same way as eq. 9).
//!
//! Usage: `let stage = ThermoStage::new(&ctx, &cfg, &buffers, maps)?;` once (the shot's heat
//! maps), then per substep `stage.step(&mut recorder, &live, dt, time)` (`sim::step` does it
//! through [`Stage`]). Initial state (section 5):
//! [`initial_thermo`].
use crate::config::{PhysicsConfig, ShotConfig};
use crate::error::Result;
use crate::gpu::buffers::ParamSlots;
use crate::gpu::live::LiveBuffer;
use crate::gpu::program::{entry_points, Dispatch, Program};
use crate::gpu::Context;
use crate::ground::{levels, noise};
use crate::sim::buffers::ParticleBuffers;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};

entry_points! {
    /// The entry point of shaders/thermo.wgsl.
    pub enum ThermoEntry in "thermo.wgsl" {
        /// Eqs. 5-11 for one substep, with the forces of eq. 6, the wind and the target pull.
        Step = "thermo_step",
    }
}

/// Uniform of shaders/thermo.wgsl (same layout). Build it with [`ThermoParams::new`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ThermoParams {
    pub dt: f32,
    pub time: f32,
    /// (the particle count is `live.count`, on the GPU)
    pub _pad0: u32,
    pub seed: u32,
    pub ground_temperature: f32,
    /// Environment lapse rate below the inversion (K/m).
    pub lapse_rate: f32,
    pub adiabatic_lapse_rate: f32,
    pub heat_source: f32,
    pub heat_height: f32,
    pub noise_cell_x: f32,
    pub noise_cell_z: f32,
    pub noise_speed: f32,
    pub noise_period_x: u32,
    pub noise_period_z: u32,
    pub noise_contrast: f32,
    pub buoyancy: f32,
    pub cloud_weight: f32,
    /// `1 - exp(-phase_rate dt)`.
    pub phase_fraction: f32,
    pub saturation_a: f32,
    pub saturation_b: f32,
    pub saturation_c: f32,
    pub latent_heat: f32,
    /// Inversion base (m; 3e38 without inversion), depth (m), warming across it (K), lapse
    /// rate above it (K/m): T0(y) of `EnvironmentConfig::temperature`.
    pub inversion_base: f32,
    pub inversion_depth: f32,
    pub inversion_strength: f32,
    pub lapse_above: f32,
    /// 1 when the noise pattern heats (`physics.heat_noise`).
    pub heat_noise: u32,
    /// Live entries of `sources`.
    pub n_sources: u32,
    /// Domain extent in x and z (m) and the periodic bits of `GridParams` (the shortest
    /// distance to a source centre wraps across periodic faces).
    pub size_x: f32,
    pub size_z: f32,
    pub periodic: u32,
    /// Layers of the horizontal-mean buoyancy profile (`physics.buoyancy_reference:
    /// layer_mean`); 0 = none.
    pub n_layers: u32,
    /// Thickness of a layer (m); the profile's values sit at the layer centres.
    pub layer_height: f32,
    /// Vapor the ground evaporates per kelvin of heating, 1 / (Bowen ratio Q) (kg/kg per K;
    /// 0 = dry ground, `physics.bowen_ratio`).
    pub ground_vapor: f32,
    /// Levels of `wind` in use (0 = no wind) and the relaxation fraction of a substep,
    /// 1 - exp(-dt / tau) ([`crate::sim::wind`]).
    pub n_wind: u32,
    pub wind_fraction: f32,
    /// `physics.thermodynamics`: 1 when atmospheric ([`Pressure`]), then the saturation of
    /// eq. 10 is multiplied by p0 / p_s (1 - y / top)^(-exponent).
    pub atmospheric: u32,
    pub pressure_top: f32,
    pub pressure_exponent: f32,
    pub pressure_surface: f32,
    /// Levels of `physics.environment.profile` (0: T0(y) from the lapse rates and inversion).
    pub n_env: u32,
    /// 0.608 (R_v / R_d - 1) with `physics.virtual_temperature`, else 0: eq. 6 then reads
    /// T (1 + virtual_factor v), which is T exactly at 0.
    pub virtual_factor: f32,
    pub _env_pad: [u32; 2],
    /// (height m, T0 K, 0, 0) by increasing height.
    pub env: [[f32; 4]; MAX_ENVIRONMENT_LEVELS],
    /// The profile (m/s^2), four layers a row: [`LayerBuoyancy`].
    pub layers: [[f32; 4]; MAX_LAYERS / 4],
    // --- art direction (issue 18): wind and sources, after everything else ---
    /// Wind levels (height m, speed m/s, heading rad, 0) ([`crate::sim::wind::rows`]).
    pub wind: [[f32; 4]; MAX_WIND_LEVELS],
    /// `physics.sources` with this substep's schedule ([`crate::sim::sources::pack`]); the
    /// heat-map entries of image sources come from [`ThermoParams::with_maps`].
    pub sources: [SourceGpu; MAX_SOURCES],
    // --- target-shape control (sim::control), after everything else ---
    /// (1 when on, offset of the supply map in the heat-map buffer, columns along x, along z);
    /// the footprint mask follows the supply map. Set by [`ThermoParams::with_maps`].
    pub control: [u32; 4],
    /// (heating K/s and vapor kg/kg/s at a supply factor of 1, top of the supplied layer (m),
    /// voxels along y).
    pub control_rate: [f32; 4],
    /// (pull m/s^2, reach m, cloud threshold kg/kg, voxel height m) of the pull towards the
    /// target; pull 0 = none.
    pub control_pull: [f32; 4],
}

pub use crate::ground::limits::MAX_ENVIRONMENT_LEVELS;
/// Most layers of the horizontal-mean buoyancy profile (`ground::limits`).
pub use crate::ground::limits::MAX_LAYERS;
pub use crate::sim::sources::{HeatMaps, SourceGpu, MAX_SOURCES};
pub use crate::sim::wind::MAX_WIND_LEVELS;

impl ThermoParams {
    /// Parameters of one substep of length `dt` (s) starting at simulated time `time` (s).
    pub fn new(cfg: &ShotConfig, dt: f64, time: f64) -> Self {
        let p = &cfg.physics;
        let (cell_x, period_x) = noise::lattice_for_extent(cfg.domain.size[0], p.heat_noise_scale);
        let (cell_z, period_z) = noise::lattice_for_extent(cfg.domain.size[2], p.heat_noise_scale);
        let (wind_levels, wind) = crate::sim::wind::relaxed_rows(cfg);
        let pressure = Pressure::of(p);
        Self {
            dt: dt as f32,
            time: time as f32,
            _pad0: 0,
            seed: noise::fold_seed(cfg.seed),
            ground_temperature: p.ground_temperature as f32,
            lapse_rate: p.environment.lapse_rate as f32,
            adiabatic_lapse_rate: p.adiabatic_lapse_rate as f32,
            heat_source: p.heat_source as f32,
            heat_height: p.heat_height as f32,
            noise_cell_x: cell_x as f32,
            noise_cell_z: cell_z as f32,
            noise_speed: p.heat_noise_speed as f32,
            noise_period_x: period_x,
            noise_period_z: period_z,
            noise_contrast: p.heat_noise_contrast as f32,
            buoyancy: p.buoyancy as f32,
            cloud_weight: p.cloud_weight as f32,
            phase_fraction: (-(-p.phase_rate * dt).exp_m1()) as f32,
            saturation_a: p.saturation_a as f32,
            saturation_b: p.saturation_b as f32,
            saturation_c: p.saturation_c as f32,
            latent_heat: p.latent_heat as f32,
            inversion_base: p.environment.inversion_height.map_or(3.0e38, |h| h as f32),
            inversion_depth: p.environment.inversion_depth as f32,
            inversion_strength: p.environment.inversion_strength as f32,
            lapse_above: p.environment.lapse_above() as f32,
            heat_noise: p.heat_noise as u32,
            n_sources: p.sources.len().min(MAX_SOURCES) as u32,
            size_x: cfg.domain.size[0] as f32,
            size_z: cfg.domain.size[2] as f32,
            periodic: crate::sim::grid_params::GridParams::for_shot(cfg).periodic,
            n_layers: 0,
            layer_height: 0.0,
            ground_vapor: p.bowen_ratio.map_or(0.0, |b| 1.0 / (b * p.latent_heat)) as f32,
            n_wind: wind_levels,
            wind_fraction: crate::sim::wind::fraction(cfg, dt),
            atmospheric: pressure.is_some() as u32,
            pressure_top: pressure.map_or(0.0, |q| q.top as f32),
            pressure_exponent: pressure.map_or(0.0, |q| q.exponent as f32),
            pressure_surface: pressure.map_or(1.0, |q| q.surface as f32),
            n_env: p.environment.profile.len().min(MAX_ENVIRONMENT_LEVELS) as u32,
            virtual_factor: virtual_factor(p) as f32,
            _env_pad: [0; 2],
            env: std::array::from_fn(|k| {
                p.environment.profile.get(k).map_or([0.0; 4], |l| {
                    [l.height as f32, l.temperature as f32, 0.0, 0.0]
                })
            }),
            wind,
            sources: crate::sim::sources::pack(cfg, dt, time),
            layers: [[0.0; 4]; MAX_LAYERS / 4],
            control: [0; 4],
            control_pull: [0.0; 4],
            control_rate: cfg.control.active_target().map_or([0.0; 4], |t| {
                [
                    t.heat as f32,
                    t.vapor as f32,
                    t.supply_height.unwrap_or(p.heat_height) as f32,
                    0.0,
                ]
            }),
        }
    }

    /// These parameters with the heat-map entries of the image sources (where each map starts
    /// in the stage's map buffer, and its size).
    pub fn with_maps(mut self, maps: &HeatMaps) -> Self {
        self.sources = maps.with_maps(self.sources);
        if let Some([offset, nx, nz, ny]) = maps.control {
            self.control = [1, offset, nx, nz];
            self.control_rate[3] = ny as f32;
            self.control_pull = maps.pull;
        }
        self
    }

    /// These parameters with the horizontal-mean buoyancy profile subtracted in eq. 6.
    pub fn with_layers(mut self, profile: &LayerBuoyancy) -> Self {
        self.n_layers = profile.values.len() as u32;
        self.layer_height = profile.layer_height as f32;
        for (k, v) in profile.values.iter().enumerate() {
            self.layers[k / 4][k % 4] = *v as f32;
        }
        self
    }
}

/// The mass-weighted horizontal mean of eq. 6's force per height (m/s^2), on layers of at
/// least one kernel radius (at most [`MAX_LAYERS`]) tiling the domain's height; a particle
/// counts for the two nearest layer centres with linear weights, and eq. 6 reads the profile
/// back with the same interpolation.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LayerBuoyancy {
    pub layer_height: f64,
    pub values: Vec<f64>,
}

impl LayerBuoyancy {
    /// The profile of a state, or none when `physics.buoyancy_reference` is `environment`.
    pub fn of_state(cfg: &ShotConfig, state: &crate::ground::ParticleState) -> Self {
        if cfg.physics.buoyancy_reference != crate::config::BuoyancyReference::LayerMean {
            return Self::default();
        }
        let height = cfg.domain.size[1];
        let h0 = cfg.domain.kernel_radius();
        let n = ((height / h0).floor() as usize).clamp(1, MAX_LAYERS);
        let layer_height = height / n as f64;
        let p = &cfg.physics;
        let (mut sum, mut mass) = (vec![0.0f64; n], vec![0.0f64; n]);
        for i in 0..state.len() {
            let y = state.pos[i][1] as f64;
            let th = state.thermo[i];
            let t0 = environment_temperature(p, y);
            let tv = th[0] as f64 * (1.0 + virtual_factor(p) * th[1] as f64);
            let force = p.buoyancy * (tv - t0) / t0 - p.cloud_weight * th[2] as f64;
            let m = levels::mass(1.0, state.info[i][1].min(levels::MAX_LEVEL));
            let (k0, k1, f) = layer_weights(y, layer_height, n);
            for (k, w) in [(k0, 1.0 - f), (k1, f)] {
                sum[k] += w * m * force;
                mass[k] += w * m;
            }
        }
        let values = sum
            .iter()
            .zip(&mass)
            .map(|(s, m)| if *m > 0.0 { s / m } else { 0.0 })
            .collect();
        Self {
            layer_height,
            values,
        }
    }
}

/// The two layers whose centres bracket height y and the weight of the upper one (clamped at
/// the lowest and highest centres). Mirror of thermo.wgsl's `layer_mean`.
pub fn layer_weights(y: f64, layer_height: f64, n: usize) -> (usize, usize, f64) {
    let t = (y / layer_height - 0.5).clamp(0.0, (n - 1) as f64);
    let k0 = t.floor() as usize;
    (k0, (k0 + 1).min(n - 1), t - k0 as f64)
}

/// Environment temperature T0(y) (K): `physics.environment` above `ground_temperature`.
/// R_v / R_d - 1: the virtual temperature is T (1 + this v) (v the vapor mixing ratio).
pub const VIRTUAL_FACTOR: f64 = 0.608;

/// The factor of v in eq. 6's temperature: [`VIRTUAL_FACTOR`] with
/// `physics.virtual_temperature`, else 0 (the paper's T).
pub fn virtual_factor(p: &PhysicsConfig) -> f64 {
    if p.virtual_temperature {
        VIRTUAL_FACTOR
    } else {
        0.0
    }
}

pub fn environment_temperature(p: &PhysicsConfig, y: f64) -> f64 {
    p.environment.temperature(p.ground_temperature, y)
}

/// Saturation vapor content A exp(B / (T + C)) (kg/kg) at height y, the first term of eq. 10
/// (times p0 / p(y) with atmospheric thermodynamics: [`Pressure`]).
pub fn saturation(p: &PhysicsConfig, temperature: f64, y: f64) -> f64 {
    let paper = p.saturation_a * (p.saturation_b / (temperature + p.saturation_c).max(1e-3)).exp();
    match Pressure::of(p) {
        Some(q) => paper * q.factor(y),
        None => paper,
    }
}

/// Dry air's c_p / R_d (1004 / 287.04).
pub const CP_OVER_RD: f64 = 3.4978;

/// Reference pressure eq. 10's constants are for (Pa): A = 0.622 x 611.2 Pa x e^17.67 / p0 is
/// Bolton's (1980) saturation mixing ratio.
pub const P0: f64 = 1.0e5;

/// The hydrostatic pressure of `physics.thermodynamics: atmospheric`: the dry adiabatic
/// reference atmosphere over the floor, p(y) = p_s (1 - y / top)^exponent with
/// top = T_s / Gamma_d and exponent = c_p / R_d.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pressure {
    pub top: f64,
    pub exponent: f64,
    /// p0 / p_s.
    pub surface: f64,
}

impl Pressure {
    /// The shot's, or none with `thermodynamics: paper`.
    pub fn of(p: &PhysicsConfig) -> Option<Self> {
        (p.thermodynamics == crate::config::Thermodynamics::Atmospheric).then(|| Self {
            top: environment_temperature(p, 0.0) / p.adiabatic_lapse_rate,
            exponent: CP_OVER_RD,
            surface: P0 / p.surface_pressure.unwrap_or(P0),
        })
    }

    /// p(y) (Pa).
    pub fn at(&self, y: f64) -> f64 {
        P0 / self.surface * (1.0 - y / self.top).powf(self.exponent)
    }

    /// p0 / p(y): how much more vapor saturates at height y than at p0.
    pub fn factor(&self, y: f64) -> f64 {
        self.surface * (1.0 - y / self.top).powf(-self.exponent)
    }
}

/// Initial thermo of a particle at height y (section 5): T = T0(y), v = kv(y) A exp(B / (T + C))
/// (kv(y) = `initial_vapor`, or `environment.humidity_above` over the inversion), or the
/// vapor of `environment.profile` when it gives one; w = 0, shape energy 0.
pub fn initial_thermo(p: &PhysicsConfig, y: f64) -> [f32; 4] {
    let t = environment_temperature(p, y);
    let vapor = p
        .environment
        .profile_vapor(y)
        .unwrap_or_else(|| p.environment.humidity(p.initial_vapor, y) * saturation(p, t, y));
    [t as f32, vapor as f32, 0.0, 0.0]
}

/// The thermodynamics pass (eqs. 5-11), bound once to the particle buffers; its parameters
/// are rewritten before every substep (time, each source's schedule).
pub struct ThermoStage {
    program: Program<ThermoEntry>,
    params: ParamSlots<ThermoParams>,
    bind: wgpu::BindGroup,
    cfg: ShotConfig,
    /// Subtracted in eq. 6 (empty unless `physics.buoyancy_reference` is `layer_mean`).
    layers: LayerBuoyancy,
    /// The image sources' heat maps ([`HeatMaps`]) and their device copy (`heat_maps`).
    maps: HeatMaps,
    map_buffer: wgpu::Buffer,
}

impl ThermoStage {
    /// The stage, with the heat maps of the image sources and, when the shot's target control
    /// is on, room for the controller's supply map and its footprint mask
    /// ([`HeatMaps::with_target`]).
    pub fn new(
        ctx: &Context,
        cfg: &ShotConfig,
        b: &ParticleBuffers,
        maps: HeatMaps,
    ) -> Result<Self> {
        let program = Program::new(ctx)?;
        let params = ParamSlots::single(ctx, "thermo params", &ThermoParams::new(cfg, 0.0, 0.0));
        let map_buffer = crate::gpu::buffers::storage_init(&ctx.device, "heat maps", &maps.values);
        let own = [
            ("P", params.slot(0)),
            ("heat_maps", map_buffer.as_entire_binding()),
        ];
        let bind = program.bind(ctx, &[&own, b])?;
        Ok(Self {
            program,
            params,
            bind,
            cfg: cfg.clone(),
            layers: LayerBuoyancy::default(),
            maps,
            map_buffer,
        })
    }

    /// The heat maps this stage samples (what the mirror needs besides the parameters).
    pub fn maps(&self) -> &HeatMaps {
        &self.maps
    }

    /// The target controller's supply per column for the next substeps (set at frame starts,
    /// written to the device with the queue before the next substep's submit: no host wait).
    pub fn set_supply(&mut self, ctx: &Context, supply: &[f32]) {
        if let Some(offset) = self.maps.set_supply(supply) {
            ctx.queue.write_buffer(
                &self.map_buffer,
                (offset * 4) as u64,
                bytemuck::cast_slice(supply),
            );
        }
    }

    /// The horizontal-mean buoyancy profile the next substeps subtract (set at frame starts).
    pub fn set_layers(&mut self, layers: LayerBuoyancy) {
        self.layers = layers;
    }

    /// Records one substep of length `dt` (s) at simulated time `time` (s).
    pub fn step(&self, rec: &mut Recorder, live: &LiveBuffer, dt: f64, time: f64) -> Result<()> {
        let params = ThermoParams::new(&self.cfg, dt, time)
            .with_layers(&self.layers)
            .with_maps(&self.maps);
        self.step_params(rec, live, &params)
    }

    /// As [`Self::step`] with explicit parameters (tests share them with the mirror).
    pub(crate) fn step_params(
        &self,
        rec: &mut Recorder,
        live: &LiveBuffer,
        params: &ThermoParams,
    ) -> Result<()> {
        // written before the submit that carries this substep, after the previous one's
        self.params.write(rec.ctx(), 0, params);
        self.program.dispatch(
            &mut rec.pass(),
            ThermoEntry::Step,
            &[(&self.bind, 0)],
            Dispatch::Live(live),
        );
        Ok(())
    }
}

impl Stage for ThermoStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        let cfg = setup.shot.config();
        Self::new(setup.ctx, cfg, setup.buffers, setup.maps.clone())
    }

    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        match phase {
            Phase::Cloud => self.step(rec, sub.live, sub.dt, sub.time),
            other => Err(crate::sim::stage::not_recorded("thermodynamics", other)),
        }
    }

    fn device_bytes(&self) -> u64 {
        self.params.size() + self.map_buffer.size()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_layout_matches_wgsl() {
        assert_eq!(std::mem::size_of::<ThermoParams>(), 1376);
    }

    /// A force that depends on height alone is the whole profile: eq. 6 less the profile is
    /// zero for every particle (to the profile's f32 rounding).
    #[test]
    fn layer_profile_is_the_mass_weighted_mean_per_height() {
        let mut cfg: ShotConfig = serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [400.0, 1000.0, 400.0], spacing: 50.0}\n\
             physics: {buoyancy_reference: layer_mean}\n",
        )
        .unwrap();
        cfg.physics.cloud_weight = 0.0;
        let mut s = crate::ground::ParticleState::default();
        for (k, y) in [10.0f32, 260.0, 480.0, 730.0, 990.0].iter().enumerate() {
            for x in 0..4 {
                let t0 = environment_temperature(&cfg.physics, *y as f64);
                // 1 K warmer per layer up, the same across the layer; mixed levels
                s.pos.push([x as f32 * 100.0, *y, 0.0, 0.0]);
                s.thermo.push([(t0 + k as f64) as f32, 0.0, 0.0, 0.0]);
                s.info.push([s.info.len() as u32, x % 3]);
                s.vel.push([0.0; 4]);
                s.density.push(1.0);
            }
        }
        let prof = LayerBuoyancy::of_state(&cfg, &s);
        assert_eq!(prof.values.len(), 10, "1000 m of 100 m kernel radii");
        let p = ThermoParams::new(&cfg, 1.0, 0.0).with_layers(&prof);
        for i in 0..s.len() {
            let y = s.pos[i][1] as f64;
            let t0 = environment_temperature(&cfg.physics, y);
            let force = cfg.physics.buoyancy * (s.thermo[i][0] as f64 - t0) / t0;
            let mean = crate::sim::reference::thermo::layer_mean(&p, y);
            assert!((force - mean).abs() < 1e-6, "{y}: {force} vs {mean}");
        }
        // off: no profile
        cfg.physics.buoyancy_reference = crate::config::BuoyancyReference::Environment;
        assert!(LayerBuoyancy::of_state(&cfg, &s).values.is_empty());
    }
}
