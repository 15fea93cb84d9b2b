//! `physics.entrainment`: the mixing of the clouds with the clear air around them that the
//! particles are too coarse to resolve, as the lateral entrainment of a cumulus (Siebesma &
//! Cuijpers 1995 measured epsilon = 1.5-2.5e-3 /m in BOMEX's clouds). The vapor mixing of the
//! smoothing pass (`physics.smoothing.vapor_diffusivity`) acts where a cloudy particle meets a
//! clear one; this reaches the inside of a cloud.
//!
//! Per particle, once a frame, before the frame's first substep moves anything
//! (shaders/entrainment.wgsl `apply_entrainment`; f64 mirror `sim::reference::entrainment`):
//! - a cloudy particle (w > 0) at height y with vertical speed u_y moves T, v and w each a
//!   fraction r = 1 - exp(-epsilon |u_y| dt) of the way to the clear air's at y (T_env =
//!   <s_l>_env - Gamma_d y, v_env = <q_t>_env, no cloud water), so that its liquid water
//!   static temperature s_l = T + Gamma_d y - Q w and total water q_t = v + w mix linearly; the
//!   next substep's phase transition evaporates what the mixture cannot hold;
//! - a clear particle takes, per unit mass, what the clouds of its layers gave up, so the pass
//!   keeps the sums of m s_l and m q_t (except where a clear particle's vapor would go below 0).
//!
//! The host builds the table from the frame-start state, on the layers of the forcing
//! (`sim::forces::forcing`, at least a kernel radius deep, linear between centres): the clear
//! particles' mass-weighted means of s_l and q_t, and each layer's gain per clear particle,
//! the clouds' loss attributed with the weights they read the clear air with. `dt` is the
//! frame's length, and the stage runs first among the forces, on exactly the state read back
//! at the end of the frame before, so the host knows what the clouds gave up: stats.jsonl's
//! `entrainment_water` (kg), the total water the clouds gave to the clear air in the frame.
use crate::config::ShotConfig;
use crate::error::Result;
use crate::gpu::program::entry_points;
use crate::ground::ParticleState;
use crate::sim::forces::forcing::MAX_FORCING_LAYERS;
use crate::sim::forces::pass::{record_once_a_frame, ParticlePass};
use crate::sim::forces::relative_mass;
use crate::sim::phase::{Phase, Recorder};
use crate::sim::stage::{Setup, Stage, Substep};
use crate::sim::thermo::layer_weights;

entry_points! {
    /// The entry point of shaders/entrainment.wgsl.
    pub enum EntrainmentEntry in "entrainment.wgsl" {
        /// One frame's entrainment, per particle.
        Apply = "apply_entrainment",
    }
}

/// Uniform of shaders/entrainment.wgsl (same layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct EntrainmentParams {
    /// The frame's length (s).
    pub dt: f32,
    /// epsilon (1/m).
    pub rate: f32,
    pub n_layers: u32,
    pub layer_height: f32,
    /// Gamma_d (K/m).
    pub lapse: f32,
    pub _pad: [u32; 3],
    /// (clear mean s_l K, clear mean q_t kg/kg, 1 where the layer holds clear air, -).
    pub env: [[f32; 4]; MAX_FORCING_LAYERS],
    /// (s_l gain K, q_t gain kg/kg, -, -) of each clear particle of the layer.
    pub gain: [[f32; 4]; MAX_FORCING_LAYERS],
}

/// A frame's entrainment, in f64: the layer table and what the clouds give up.
#[derive(Debug, Clone, PartialEq)]
pub struct EntrainmentTable {
    pub seconds: f64,
    pub rate: f64,
    pub layer_height: f64,
    /// (clear mean s_l, clear mean q_t), `None` where the layer holds no clear air.
    pub env: Vec<Option<[f64; 2]>>,
    /// (s_l, q_t) each clear particle of the layer gains.
    pub gain: Vec<[f64; 2]>,
    /// Sums over the cloudy particles of m (s_l, q_t) given up, in level-0 masses.
    pub given: [f64; 2],
}

/// The weights a cloudy particle at height y reads the clear air with: those of its two layer
/// centres that hold clear air, normalised; `None` when neither does.
fn cloud_weights(env: &[Option<[f64; 2]>], y: f64, layer_height: f64) -> Option<[(usize, f64); 2]> {
    let (k0, k1, t) = layer_weights(y, layer_height, env.len());
    let a = if env[k0].is_some() { 1.0 - t } else { 0.0 };
    let b = if env[k1].is_some() { t } else { 0.0 };
    (a + b > 0.0).then(|| [(k0, a / (a + b)), (k1, b / (a + b))])
}

impl EntrainmentTable {
    /// The table of a frame of `seconds` starting from `state`.
    pub fn of_state(cfg: &ShotConfig, state: &ParticleState, seconds: f64) -> Self {
        let (n, layer_height) = crate::sim::forces::frame_layers(cfg);
        let p = &cfg.physics;
        let rate = p.entrainment;
        let conserved = |i: usize| {
            let th = state.thermo[i].map(|v| v as f64);
            let y = state.pos[i][1] as f64;
            [
                th[0] + p.adiabatic_lapse_rate * y - p.latent_heat * th[2],
                th[1] + th[2],
            ]
        };
        let cloudy = |i: usize| state.thermo[i][2] > 0.0;
        // the clear air's mass-weighted means, each particle shared by its two layer centres
        let (mut sum, mut mass) = (vec![[0.0; 2]; n], vec![0.0; n]);
        for i in (0..state.len()).filter(|&i| !cloudy(i)) {
            let m = relative_mass(state, i);
            let phi = conserved(i);
            let (k0, k1, t) = layer_weights(state.pos[i][1] as f64, layer_height, n);
            for (k, w) in [(k0, 1.0 - t), (k1, t)] {
                sum[k][0] += w * m * phi[0];
                sum[k][1] += w * m * phi[1];
                mass[k] += w * m;
            }
        }
        let env: Vec<Option<[f64; 2]>> = (0..n)
            .map(|k| (mass[k] > 0.0).then(|| [sum[k][0] / mass[k], sum[k][1] / mass[k]]))
            .collect();
        // what each cloudy particle gives up, attributed to the layers it read the clear air of
        let mut lost = vec![[0.0; 2]; n];
        let mut given = [0.0; 2];
        for i in (0..state.len()).filter(|&i| cloudy(i)) {
            let y = state.pos[i][1] as f64;
            let Some(weights) = cloud_weights(&env, y, layer_height) else {
                continue;
            };
            let r = -(-rate * (state.vel[i][1] as f64).abs() * seconds).exp_m1();
            let m = relative_mass(state, i);
            let phi = conserved(i);
            let mut at_y = [0.0; 2];
            for (k, w) in weights {
                if let Some(e) = env[k] {
                    at_y[0] += w * e[0];
                    at_y[1] += w * e[1];
                }
            }
            let out = [0, 1].map(|c| m * r * (phi[c] - at_y[c]));
            for (k, w) in weights {
                lost[k][0] += w * out[0];
                lost[k][1] += w * out[1];
            }
            given[0] += out[0];
            given[1] += out[1];
        }
        let gain = (0..n)
            .map(|k| match mass[k] > 0.0 {
                true => [lost[k][0] / mass[k], lost[k][1] / mass[k]],
                false => [0.0; 2],
            })
            .collect();
        Self {
            seconds,
            rate,
            layer_height,
            env,
            gain,
            given,
        }
    }

    /// The uniform of the table.
    pub fn params(&self, lapse: f64) -> EntrainmentParams {
        let mut env = [[0.0f32; 4]; MAX_FORCING_LAYERS];
        let mut gain = [[0.0f32; 4]; MAX_FORCING_LAYERS];
        for (k, e) in self.env.iter().enumerate() {
            if let Some([s, q]) = e {
                env[k] = [*s as f32, *q as f32, 1.0, 0.0];
            }
            gain[k] = [self.gain[k][0] as f32, self.gain[k][1] as f32, 0.0, 0.0];
        }
        EntrainmentParams {
            dt: self.seconds as f32,
            rate: self.rate as f32,
            n_layers: self.env.len() as u32,
            layer_height: self.layer_height as f32,
            lapse: lapse as f32,
            _pad: [0; 3],
            env,
            gain,
        }
    }
}

/// The entrainment stage: one pass at the start of each frame.
pub struct EntrainmentStage {
    pass: ParticlePass<EntrainmentEntry, EntrainmentParams>,
    cfg: ShotConfig,
    /// The uniform of the frame being simulated, and the total water its clouds give up (kg).
    frame: EntrainmentParams,
    water: f64,
}

/// The stage, when the shot has `physics.entrainment` (its line in `sim::forces::FORCES`).
pub fn stage(setup: &Setup) -> Result<Option<Box<dyn Stage>>> {
    Ok(match setup.shot.config().physics.entrainment > 0.0 {
        true => Some(Box::new(EntrainmentStage::from_setup(setup)?)),
        false => None,
    })
}

impl EntrainmentStage {
    fn table(&self, state: &ParticleState) -> EntrainmentTable {
        EntrainmentTable::of_state(&self.cfg, state, self.cfg.output.frame_seconds)
    }
}

impl Stage for EntrainmentStage {
    fn from_setup(setup: &Setup) -> Result<Self> {
        let cfg = setup.shot.config().clone();
        let lapse = cfg.physics.adiabatic_lapse_rate;
        let frame = EntrainmentTable::of_state(&cfg, &ParticleState::default(), 0.0).params(lapse);
        let entry = EntrainmentEntry::Apply;
        Ok(Self {
            pass: ParticlePass::new(setup, entry, "E", "entrainment params", &frame)?,
            cfg,
            frame,
            water: 0.0,
        })
    }

    fn record(&self, phase: Phase, rec: &mut Recorder, sub: &Substep) -> Result<()> {
        record_once_a_frame("entrainment", &self.pass, &self.frame, phase, rec, sub)
    }

    fn device_bytes(&self) -> u64 {
        self.pass.device_bytes()
    }

    fn reads_state(&self) -> bool {
        true
    }

    fn start_frame(&mut self, state: &ParticleState) {
        let table = self.table(state);
        self.frame = table.params(self.cfg.physics.adiabatic_lapse_rate);
        self.water = table.given[1] * self.cfg.cell_mass();
    }

    fn frame_figures(&self, out: &mut Vec<(&'static str, f64)>) {
        out.push(("entrainment_water", self.water));
    }
}

#[cfg(feature = "test-hooks")]
impl EntrainmentStage {
    /// One pass with explicit parameters (the tests share them with the mirror).
    pub fn apply_with(
        &self,
        rec: &mut Recorder,
        live: &crate::gpu::live::LiveBuffer,
        params: &EntrainmentParams,
    ) -> Result<()> {
        self.pass.record(rec, live, params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> ShotConfig {
        serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [1000.0, 1000.0, 1000.0], spacing: 50.0}\n\
             physics: {entrainment: 2.0e-3}\n",
        )
        .unwrap()
    }

    /// Particles at (height, speed up, [T, v, w], level).
    fn state(points: &[(f64, f64, [f64; 3], u32)]) -> ParticleState {
        ParticleState {
            pos: points.iter().map(|p| [0.0, p.0 as f32, 0.0, 0.0]).collect(),
            vel: points.iter().map(|p| [0.0, p.1 as f32, 0.0, 0.0]).collect(),
            thermo: points
                .iter()
                .map(|p| [p.2[0] as f32, p.2[1] as f32, p.2[2] as f32, 0.0])
                .collect(),
            info: points.iter().map(|p| [0, p.3]).collect(),
            density: Vec::new(),
        }
    }

    #[test]
    fn params_layout_matches_wgsl() {
        // 8 scalars, then two arrays of 64 vec4 (shaders/entrainment.wgsl `EntrainmentParams`)
        assert_eq!(
            std::mem::size_of::<EntrainmentParams>(),
            32 + 2 * MAX_FORCING_LAYERS * 16
        );
    }

    /// One cloudy particle rising at 1 m/s among clear ones of one layer: it gives up the
    /// fraction 1 - exp(-epsilon u_y dt) of its excess over the clear air's mean, and the clear
    /// particles of the layer (one of them of half mass) share it per unit mass.
    #[test]
    fn the_clouds_give_the_clear_air_what_they_lose() {
        let c = cfg();
        let (g, q) = (c.physics.adiabatic_lapse_rate, c.physics.latent_heat);
        // 100 m layers (h0 = 100 m); every particle at a layer centre, 250 m
        let y = 250.0;
        let s = state(&[
            (y, 1.0, [290.0, 0.012, 0.001], 0),
            (y, 0.0, [289.0, 0.008, 0.0], 0),
            (y, -3.0, [289.5, 0.010, 0.0], 1),
        ]);
        let t = EntrainmentTable::of_state(&c, &s, 60.0);
        let sl = |th: [f64; 3]| th[0] + g * y - q * th[2];
        let env = [
            (289.0 + 0.5 * 289.5) / 1.5 + g * y,
            (0.008 + 0.5 * 0.010) / 1.5,
        ];
        let got = t.env[2].unwrap();
        // to the f32 rounding of the state's vapor and water (1e-9 kg/kg)
        assert!(
            (got[0] - env[0]).abs() < 1e-4 && (got[1] - env[1]).abs() < 1e-9,
            "{got:?}"
        );
        let r = 1.0 - (-2.0e-3 * 60.0f64).exp();
        let lost = [
            r * (sl([290.0, 0.012, 0.001]) - env[0]),
            r * (0.013 - env[1]),
        ];
        assert!(
            (t.given[0] - lost[0]).abs() < 1e-4,
            "{:?} vs {lost:?}",
            t.given
        );
        assert!(
            (t.given[1] - lost[1]).abs() < 1e-9,
            "{:?} vs {lost:?}",
            t.given
        );
        // the clear air's 1.5 level-0 masses take it all
        assert!((t.gain[2][0] * 1.5 - t.given[0]).abs() < 1e-12);
        assert!((t.gain[2][1] * 1.5 - t.given[1]).abs() < 1e-15);
        // the other layers hold no particle: no clear air, no gain
        assert!(t.env[0].is_none() && t.gain[0] == [0.0; 2]);
    }

    /// Clouds in a layer without clear air give nothing; a cloud between a clear layer and an
    /// all-cloud one mixes with the clear one alone.
    #[test]
    fn clouds_without_clear_air_keep_what_they_have() {
        let c = cfg();
        let s = state(&[
            (250.0, 2.0, [290.0, 0.012, 0.001], 0),
            (350.0, 2.0, [289.0, 0.012, 0.001], 0),
        ]);
        let t = EntrainmentTable::of_state(&c, &s, 60.0);
        assert_eq!(t.given, [0.0; 2]);
        let s = state(&[
            (300.0, 2.0, [290.0, 0.012, 0.001], 0),
            (350.0, 2.0, [290.0, 0.012, 0.001], 0),
            (250.0, 0.0, [289.0, 0.008, 0.0], 0),
        ]);
        let t = EntrainmentTable::of_state(&c, &s, 60.0);
        assert!(t.env[3].is_none());
        // every loss lands on layer 2, the only one with clear air
        assert!(t.given[1] > 0.0);
        assert!((t.gain[2][1] - t.given[1]).abs() < 1e-15, "{:?}", t.gain);
        assert_eq!(t.gain[3], [0.0; 2]);
    }
}
