//! The shot config schema. Every field is documented in docs/CONFIG.md (unit, default, range).
//! Units: metres, seconds, kelvin; water contents (vapor, cloud) in kg of water per kg of air.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShotConfig {
    /// Shot name: prefix of every output file.
    pub shot: String,
    /// Seed of every random choice (initial velocities, heating noise).
    #[serde(default = "d_seed")]
    pub seed: u64,
    pub output: OutputConfig,
    pub domain: DomainConfig,
    #[serde(default)]
    pub solver: SolverConfig,
    #[serde(default)]
    pub physics: PhysicsConfig,
    #[serde(default)]
    pub adaptive: AdaptiveConfig,
    #[serde(default)]
    pub gpu: GpuConfig,
    #[serde(default)]
    pub export: ExportConfig,
    #[serde(default)]
    pub checkpoint: CheckpointConfig,
    /// Art-direction control (docs/CONFIG.md "control"); left out of the serialisation when
    /// unset, so the hashes and manifests of shots without it are unchanged.
    #[serde(default, skip_serializing_if = "ControlConfig::is_unset")]
    pub control: ControlConfig,
}
fn d_seed() -> u64 {
    1
}

impl ShotConfig {
    /// The air a level-0 particle stands for, rho0 d^3 (kg), defined here alone: the box at
    /// rest density shared among the lattice's particles. The reported masses (stats.jsonl's
    /// `total_water`, `cloud_mass`, `water_input`) and the splat's particle volumes (V = m / rho,
    /// d^3 at rest) use it. It is not the solver's m0 (`shot::Shot::m0`, rho0 over the lattice's
    /// poly6 sum: 0.97% less at h0 = 2d), and must not become it: m0 corrects the discrete kernel
    /// sum so that the lattice sits at rest density (docs/ARCHITECTURE.md "Units and choices"),
    /// it does not make the box hold 1% less air.
    pub fn cell_mass(&self) -> f64 {
        let d = self.domain.spacing;
        self.solver.rest_density * d * d * d
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    /// Run directory when `--out` is not given.
    #[serde(default = "d_out_dir")]
    pub dir: String,
    pub frames: FrameRange,
    /// Frames per second of the sequence (metadata for renderers).
    #[serde(default = "d_fps")]
    pub fps: f64,
    /// Simulated seconds per frame.
    #[serde(default = "d_frame_seconds")]
    pub frame_seconds: f64,
    /// Fewest simulation substeps per frame; more are taken where `cfl` asks for them.
    #[serde(default = "d_substeps")]
    pub substeps: u32,
    /// Most substeps per frame the CFL control may take.
    #[serde(default = "d_max_substeps")]
    pub max_substeps: u32,
    /// CFL number: a substep moves no particle farther than `cfl` times its kernel radius.
    #[serde(default = "d_cfl")]
    pub cfl: f64,
    /// Digits of the frame number in file names.
    #[serde(default = "d_padding")]
    pub frame_padding: u32,
    /// Simulated seconds before the first written frame (`preroll_frames`: rounded up to whole
    /// frames); the state is simulated, not written. Left out of the serialisation when 0, so
    /// the hashes and manifests of shots without it are unchanged.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub preroll: f64,
    #[serde(default)]
    pub preview: PreviewConfig,
}
fn d_out_dir() -> String {
    "out".into()
}
fn d_fps() -> f64 {
    24.0
}
fn d_frame_seconds() -> f64 {
    4.0
}
fn d_substeps() -> u32 {
    2
}
fn d_max_substeps() -> u32 {
    64
}
fn d_cfl() -> f64 {
    0.4
}
fn d_padding() -> u32 {
    4
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameRange {
    pub start: u32,
    pub end: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PreviewConfig {
    #[serde(default)]
    pub enabled: bool,
    #[serde(default = "d_preview_res")]
    pub resolution: [u32; 2],
    /// Also write a linear RGBA EXR next to each PNG.
    #[serde(default)]
    pub exr: bool,
    /// Unit vector towards the sun (normalised on load).
    #[serde(default = "d_sun_dir")]
    pub sun_direction: [f64; 3],
    #[serde(default = "d_sun_color")]
    pub sun_color: [f64; 3],
    #[serde(default = "d_sun_intensity")]
    pub sun_intensity: f64,
    /// Extinction per unit of density per metre (with `density_mode: fixed`).
    #[serde(default = "d_density_scale")]
    pub density_scale: f64,
    /// `physical`: the density grid's physical extinction (`export.optics`), as
    /// tools/render_blender.py renders it; `fixed`: `density_scale`.
    #[serde(default)]
    pub density_mode: DensityMode,
    /// Camera; `None` = auto-framed from the side.
    #[serde(default)]
    pub camera: Option<CameraConfig>,
    /// Also encode the previews as an H.264 MP4 (`preview/<shot>.mp4`, needs ffmpeg).
    #[serde(default)]
    pub movie: bool,
    /// Draw the heat sources' footprints (and wireframes in the air) into the previews
    /// (`preview::overlay::sources`). Left out of the serialisation when off, so the hashes and
    /// manifests of earlier shots are unchanged.
    #[serde(default, skip_serializing_if = "is_false")]
    pub source_overlay: bool,
}
fn is_false(b: &bool) -> bool {
    !*b
}
fn is_one(x: &u32) -> bool {
    *x == 1
}
fn is_zero(x: &f64) -> bool {
    *x == 0.0
}
fn d_preview_res() -> [u32; 2] {
    [640, 360]
}
/// How the preview turns density into extinction.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DensityMode {
    /// The density grid's physical extinction. `auto` (an optical depth of 4 through the core,
    /// until the physical optics replaced it) is read as this, so older runs still resume and
    /// re-render.
    #[default]
    #[serde(alias = "auto")]
    Physical,
    Fixed,
}
/// tools/render_blender.py's sun: 40 degrees high from +x, a little towards +z (the camera's
/// side); in Blender's z-up frame (0.7198, -0.2620, 0.6428).
fn d_sun_dir() -> [f64; 3] {
    [0.719_846, 0.642_788, 0.262_003]
}
/// The Nishita sky's sun at 40 degrees, as render_blender.py's sun lamp (colour and irradiance).
fn d_sun_color() -> [f64; 3] {
    [1.0, 0.812, 0.613]
}
fn d_sun_intensity() -> f64 {
    145.5
}
fn d_density_scale() -> f64 {
    0.15
}
impl Default for PreviewConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            resolution: d_preview_res(),
            exr: false,
            sun_direction: d_sun_dir(),
            sun_color: d_sun_color(),
            sun_intensity: d_sun_intensity(),
            density_scale: d_density_scale(),
            density_mode: DensityMode::Physical,
            camera: None,
            movie: false,
            source_overlay: false,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    pub position: [f64; 3],
    pub look_at: [f64; 3],
    /// Vertical field of view, degrees.
    #[serde(default = "d_fov")]
    pub fov_deg: f64,
}
fn d_fov() -> f64 {
    45.0
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomainConfig {
    /// Box size [x, y, z] in metres; y is up. The box spans [0, size].
    pub size: [f64; 3],
    /// Initial particle spacing d (metres).
    pub spacing: f64,
    /// Kernel radius as a multiple of the spacing: h0 = kernel_ratio * spacing.
    #[serde(default = "d_kernel_ratio")]
    pub kernel_ratio: f64,
    /// Periodic axes; the rest are walls. y (up) is always walled.
    #[serde(default = "d_periodic")]
    pub periodic: Vec<Axis>,
    /// The floor and the ceiling push the air along their normal alone (free slip): their
    /// wall particles, a lattice at rest, otherwise drag the air that slides over them
    /// towards the shot's frame (docs/PHYSICS.md "Walls"). Left out of the serialisation when
    /// false, so earlier hashes are unchanged.
    #[serde(default, skip_serializing_if = "is_false")]
    pub free_slip: bool,
}
fn d_kernel_ratio() -> f64 {
    2.0
}
fn d_periodic() -> Vec<Axis> {
    vec![Axis::X, Axis::Z]
}
impl DomainConfig {
    /// The level-0 kernel radius h0 = spacing * kernel_ratio (m), defined here alone.
    pub fn kernel_radius(&self) -> f64 {
        self.spacing * self.kernel_ratio
    }

    /// Particles per axis of the initial lattice and its spacing per axis, defined here alone:
    /// `round(size / spacing)` cells (at least 1) of edge `size / n` (= spacing when it divides
    /// the box, as validation asks for periodic axes).
    pub fn lattice(&self) -> ([usize; 3], [f64; 3]) {
        let n = self
            .size
            .map(|s| ((s / self.spacing).round() as usize).max(1));
        let d = [0, 1, 2].map(|a| self.size[a] / n[a] as f64);
        (n, d)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Z,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverConfig {
    /// PBF density iterations per `reference_step` of simulated time (see
    /// `crate::sim::iterations_in_substep`).
    pub iterations: u32,
    /// Spread a frame's density iterations, round(iterations frame_seconds / reference_step),
    /// evenly over its substeps (at least one each), instead of rounding each substep's share
    /// (at most `iterations`): the iteration rate, which damps buoyant motion, then does not
    /// change with the substep count the CFL control takes. Left out of the serialisation when
    /// false, so earlier hashes are unchanged.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub spread_iterations: bool,
    /// The fewest density iterations a substep runs, whatever its share (at most
    /// `iterations`). One Jacobi projection a substep does not hold the density when the CFL
    /// control takes many short substeps (docs/PHYSICS.md "BOMEX"). Left out of the
    /// serialisation at 1, so earlier hashes are unchanged.
    #[serde(skip_serializing_if = "is_one")]
    pub min_iterations: u32,
    /// Rest density rho0 (kg/m^3).
    pub rest_density: f64,
    /// Constraint force mixing epsilon (eq. 4 relaxation), dimensionless: eps = relaxation / h0^2
    /// (the lattice value of sum |grad C|^2 is 1.46 / h0^2 at h0 = 2d).
    pub relaxation: f64,
    /// Artificial pressure s_corr = -k (W / W(dq h))^n h_i h_j: k (dimensionless), n and
    /// delta q (fraction of h).
    pub scorr_k: f64,
    pub scorr_n: u32,
    pub scorr_dq: f64,
    /// XSPH viscosity c: the fraction of the velocity difference to the neighbours' average
    /// removed per `reference_step` seconds of simulated time.
    pub xsph: f64,
    /// Under-density (fraction of rho0) the density constraint leaves alone; larger voids are
    /// filled. Split particles get `split_expansion_weight` of the rest.
    pub expansion_tolerance: f64,
    /// The share of the under-density correction (beyond `expansion_tolerance`) that split
    /// particles get: 0 = compression only, 1 = two-sided like level 0.
    pub split_expansion_weight: f64,
    /// Simulated time (s) over which `solver.xsph` and `physics.smoothing.kappa` apply their
    /// fraction: a substep of dt applies 1 - (1 - c)^(dt / reference_step), so the look does
    /// not change with the number of substeps.
    pub reference_step: f64,
    /// Vorticity confinement epsilon (m/s): acceleration = vorticity * (N x omega).
    pub vorticity: f64,
    /// Constant gravity (m/s^2, downward); 0 = none (paper example 1).
    pub gravity: f64,
    /// Speeds are clamped to this (m/s) as a safety net.
    pub max_speed: f64,
}
impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            iterations: 4,
            spread_iterations: false,
            min_iterations: 1,
            rest_density: 1.0,
            relaxation: 1.0,
            scorr_k: 0.1,
            scorr_n: 4,
            scorr_dq: 0.2,
            xsph: 0.01,
            reference_step: 4.0,
            expansion_tolerance: 0.01,
            split_expansion_weight: 0.25,
            vorticity: 0.0,
            gravity: 0.0,
            max_speed: 30.0,
        }
    }
}
impl SolverConfig {
    /// The share of `reference_step` a substep of `dt` seconds is, dt / reference_step, defined
    /// here alone: the solver's per-reference-step rates (the density iterations, XSPH, s_corr)
    /// scale by it, so a frame does as much at 2 substeps as at 8 (docs/PHYSICS.md "Substeps").
    pub fn step_share(&self, dt: f64) -> f64 {
        dt / self.reference_step
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PhysicsConfig {
    /// Environment temperature at the floor (K).
    pub ground_temperature: f64,
    /// Environment temperature profile T0(y) above the floor.
    pub environment: EnvironmentConfig,
    /// Dry adiabatic lapse rate Gamma_d (K per metre), eq. 7.
    pub adiabatic_lapse_rate: f64,
    /// Ground heating Se (K/s), eq. 5, applied below `heat_height`, modulated by noise.
    pub heat_source: f64,
    /// Whether the noise pattern heats the ground (`heat_source` x noise); the `sources` add to
    /// it. `on`/`off` are accepted besides `true`/`false`.
    #[serde(deserialize_with = "on_off")]
    pub heat_noise: bool,
    /// Heat and vapor sources besides the noise pattern (shapes on the ground and in the air,
    /// a painted heat map).
    pub sources: Vec<HeatSource>,
    pub heat_height: f64,
    /// Feature size of the heating noise over the ground (m) and its change rate (1/s).
    pub heat_noise_scale: f64,
    pub heat_noise_speed: f64,
    /// Contrast of the heating pattern: the heat fraction is clamp((n - 0.5) contrast + 0.5,
    /// 0, 1) for noise n in [0, 1); 1 = plain noise, larger = distinct hot patches.
    pub heat_noise_contrast: f64,
    /// Buoyancy k_b (m/s^2) and cloud weight k_g (m/s^2 per kg/kg), eq. 6.
    pub buoyancy: f64,
    pub cloud_weight: f64,
    /// What eq. 6's force is measured against: the environment T0(y) alone, or also less its
    /// horizontal mean per height (`layer_mean`).
    pub buoyancy_reference: BuoyancyReference,
    /// Eq. 6 on the virtual temperature T (1 + 0.608 v): moist air is lighter (a kelvin of
    /// buoyancy per 5.5 g/kg of vapor at 300 K). Needs `buoyancy_reference: layer_mean`, which
    /// takes away the environment's own (unknown) virtual profile. Left out of the
    /// serialisation when false, so earlier hashes are unchanged.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub virtual_temperature: bool,
    /// Phase transition rate alpha (1/s), eq. 9.
    pub phase_rate: f64,
    /// How the saturation depends on height: as eq. 10 (`paper`), or also on a hydrostatic
    /// pressure (`atmospheric`). Left out of the serialisation when `paper`, so the hashes of
    /// earlier shots are unchanged.
    #[serde(skip_serializing_if = "Thermodynamics::is_paper")]
    pub thermodynamics: Thermodynamics,
    /// Pressure at the floor (Pa) with `thermodynamics: atmospheric`; `null` = 1e5 Pa, the
    /// pressure eq. 10's constants are for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub surface_pressure: Option<f64>,
    /// Saturation gamma = A exp(B / (T + C)), eq. 10.
    pub saturation_a: f64,
    pub saturation_b: f64,
    pub saturation_c: f64,
    /// Latent heat Q (K per kg/kg), eq. 11.
    pub latent_heat: f64,
    /// Initial vapor as a fraction of saturation (kv, section 5).
    pub initial_vapor: f64,
    /// Bowen ratio of the heated ground (sensible over latent heat flux): with it the ground
    /// evaporates heating / (bowen_ratio latent_heat) of vapor; `null` = dry ground (paper).
    pub bowen_ratio: Option<f64>,
    /// Maximum initial speed (m/s), random directions.
    pub initial_speed: f64,
    pub smoothing: SmoothingConfig,
    /// Horizontal wind profile the air relaxes towards; `None` = no wind. Left out of the
    /// serialisation when unset, so the hashes of shots without wind are unchanged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wind: Option<WindConfig>,
    /// Large-scale forcing in physical units (surface fluxes, radiation, a moisture tendency,
    /// subsidence; `sim::forces::forcing`); `None` = none. Left out of the serialisation when
    /// unset, so the hashes of shots without it are unchanged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub forcing: Option<ForcingConfig>,
    /// Fractional entrainment rate epsilon (1/m): once a frame each cloudy particle mixes with
    /// the clear air of its height a fraction 1 - exp(-epsilon |w| dt) of the way, and the clear
    /// air there takes what the clouds give up (`sim::forces::entrainment`); 0 = none. Left out
    /// of the serialisation when 0, so the hashes of shots without it are unchanged.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub entrainment: f64,
}
/// `true`/`false`, or the words `on`/`off` (YAML 1.2 reads those as strings).
fn on_off<'de, D: serde::Deserializer<'de>>(d: D) -> Result<bool, D::Error> {
    struct V;
    impl serde::de::Visitor<'_> for V {
        type Value = bool;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("true or false (or on / off)")
        }
        fn visit_bool<E: serde::de::Error>(self, b: bool) -> Result<bool, E> {
            Ok(b)
        }
        fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<bool, E> {
            match s {
                "on" => Ok(true),
                "off" => Ok(false),
                _ => Err(E::invalid_value(serde::de::Unexpected::Str(s), &self)),
            }
        }
    }
    d.deserialize_any(V)
}
impl Default for PhysicsConfig {
    fn default() -> Self {
        Self {
            ground_temperature: 295.0,
            environment: EnvironmentConfig::default(),
            adiabatic_lapse_rate: 0.0098,
            heat_source: 0.15,
            heat_noise: true,
            sources: Vec::new(),
            heat_height: 100.0,
            heat_noise_scale: 400.0,
            heat_noise_speed: 0.002,
            heat_noise_contrast: 3.0,
            buoyancy: 9.81,
            cloud_weight: 9.81,
            buoyancy_reference: BuoyancyReference::Environment,
            virtual_temperature: false,
            phase_rate: 0.05,
            thermodynamics: Thermodynamics::Paper,
            surface_pressure: None,
            saturation_a: 1.79e5,
            saturation_b: -4302.6,
            saturation_c: -29.65,
            latent_heat: 2500.0,
            initial_vapor: 0.8,
            bowen_ratio: None,
            initial_speed: 0.5,
            smoothing: SmoothingConfig::default(),
            wind: None,
            forcing: None,
            entrainment: 0.0,
        }
    }
}

/// T0(y): `lapse_rate` up to the inversion base, a rise of `inversion_strength` over
/// `inversion_depth`, then `lapse_rate_above`; piecewise linear and continuous.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvironmentConfig {
    /// K per metre below the inversion (positive = cooler aloft).
    pub lapse_rate: f64,
    /// Height of the inversion base (m); `null` = no inversion.
    pub inversion_height: Option<f64>,
    /// Thickness of the inversion layer (m).
    pub inversion_depth: f64,
    /// Warming across the inversion layer (K).
    pub inversion_strength: f64,
    /// K per metre above the inversion; `null` = `lapse_rate`.
    pub lapse_rate_above: Option<f64>,
    /// Initial vapor above the inversion as a fraction of saturation (the dry free air over
    /// the boundary layer); linear across the inversion layer; `null` = `initial_vapor`.
    pub humidity_above: Option<f64>,
    /// Measured or prescribed levels (an atmospheric case's sounding): T0(y), and the initial
    /// vapor when every level gives it, linear between levels and constant outside. When
    /// given, `ground_temperature`, `lapse_rate`, `lapse_rate_above` and the inversion keys
    /// are not read. Left out of the serialisation when empty (hashes unchanged).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub profile: Vec<EnvironmentLevel>,
    /// Random initial perturbations of temperature and vapor below a height (an LES case's
    /// trigger of turbulence, e.g. BOMEX's +-0.1 K and +-0.025 g/kg below 1600 m); `null` =
    /// none. Left out of the serialisation when unset (hashes unchanged).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<Perturbation>,
}

/// `physics.environment.perturbation`: each particle below `height` starts with temperature
/// and vapor offsets drawn uniformly from [-amplitude, +amplitude].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Perturbation {
    /// Largest temperature offset (K).
    pub temperature: f64,
    /// Largest vapor offset (kg/kg).
    pub vapor: f64,
    /// Particles at or above this height (m) are left alone.
    pub height: f64,
}

/// One level of `physics.environment.profile`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentLevel {
    /// Height above the ground (m).
    pub height: f64,
    /// Environment temperature T0 (K).
    pub temperature: f64,
    /// Initial vapor (kg/kg); given at every level or at none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vapor: Option<f64>,
}
impl Default for EnvironmentConfig {
    fn default() -> Self {
        Self {
            lapse_rate: 0.0065,
            inversion_height: None,
            inversion_depth: 100.0,
            inversion_strength: 0.0,
            lapse_rate_above: None,
            humidity_above: None,
            profile: Vec::new(),
            perturbation: None,
        }
    }
}

/// A heat and vapor source (docs/CONFIG.md "physics.sources"). Ground shapes (`disc`,
/// `ellipse`, a `box` with a 2-value centre, `image`) act on the air below `height` over their
/// footprint; volume shapes (`sphere`, a `box` with a 3-value centre) wherever they are. Keys a
/// shape does not use must be left out (validation says which). Optional keys are left out of
/// the serialisation when unset, so the hashes of earlier shots are unchanged.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeatSource {
    pub shape: SourceShape,
    /// Centre (m): (x, z) on the ground, or (x, y, z) for a sphere or a box in the air; none for
    /// an image (it covers the whole ground).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub center: Vec<f64>,
    /// Disc and sphere radius (m): full strength out to 0.7 radius, a smoothstep to 0 at it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Ellipse semi-axes (m) along x and z before the rotation by `angle`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radii: Option<[f64; 2]>,
    /// Box edge lengths (m): (x, z) on the ground or (x, y, z) in the air.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<Vec<f64>>,
    /// Rotation of an ellipse or box about the vertical axis (degrees, from +x towards +z).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle: Option<f64>,
    /// Top of the heated layer of a ground shape (m); `None` = `physics.heat_height`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<f64>,
    /// Greyscale heat map (PNG or OpenEXR) over the domain's x/z extent; a relative path is
    /// resolved against the config file's directory when the config is loaded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    /// SHA-256 of `image`, filled in when the config is loaded (so the manifest and the
    /// checkpoints pin the map); a value given in the file must match the image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image_sha256: Option<String>,
    /// Heating at full strength (K/s).
    #[serde(default)]
    pub strength: f64,
    /// Vapor added at full strength (kg/kg per s); `None` = 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vapor: Option<f64>,
    /// Simulated time it switches on (s).
    #[serde(default)]
    pub start: f64,
    /// Simulated time it switches off (s); `None` = never.
    #[serde(default)]
    pub end: Option<f64>,
    /// Smoothstep fade in after `start` and out before `end` (s).
    #[serde(default)]
    pub ramp: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceShape {
    Disc,
    Ellipse,
    Box,
    Sphere,
    Image,
}

/// `physics.wind`: a horizontal wind over height that the air relaxes towards.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindConfig {
    /// Relaxation time tau (s): each substep of dt moves a particle's horizontal velocity the
    /// fraction 1 - exp(-dt / tau) of the way to the profile.
    #[serde(default = "d_wind_time")]
    pub time_constant: f64,
    /// Levels by increasing height; linear in speed and direction between them, constant
    /// below the first and above the last. With `coriolis`, the geostrophic wind.
    pub profile: Vec<WindLevel>,
    /// Coriolis parameter f (1/s; 2 Omega sin(latitude), positive in the northern hemisphere):
    /// with it the profile is the geostrophic wind U_g and the air turns about it,
    /// du_h/dt = -f y x (u_h - U_g), in place of the relaxation (`sim::forces::coriolis`).
    /// Left out of the serialisation when unset, as the three keys below at their defaults.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coriolis: Option<f64>,
    /// Surface friction velocity u* (m/s): the particles below `surface_layer` take the surface
    /// stress, du_h/dt = -u*^2 U / (|U| d) with U their velocity over the ground; 0 = none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub surface_friction: f64,
    /// Depth d of the layer that takes the surface stress (m); `null` = the kernel radius.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface_layer: Option<f64>,
    /// The ground's velocity in the shot's frame (m/s, along x and z): a shot simulated in a
    /// frame moving with the wind (as an LES's Galilean transform) drags against the ground
    /// moving under it.
    #[serde(default, skip_serializing_if = "is_still")]
    pub ground_velocity: [f64; 2],
    /// The wind the particles start with (levels as `profile`'s, added to the random initial
    /// speeds); empty = they start at rest. An atmospheric case starts from its observed wind,
    /// not from the geostrophic one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub initial: Vec<WindLevel>,
}
pub(crate) fn d_wind_time() -> f64 {
    60.0
}
fn is_still(v: &[f64; 2]) -> bool {
    *v == [0.0; 2]
}

impl WindConfig {
    /// Whether the Coriolis and drag stage runs (`sim::forces::coriolis`).
    pub fn has_momentum_forcing(&self) -> bool {
        self.coriolis.is_some() || self.surface_friction > 0.0
    }
}

/// `physics.forcing`: the large-scale forcing of an atmospheric case (GCSS BOMEX and the like),
/// applied to every particle once a frame (docs/CONFIG.md "Forcing").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ForcingConfig {
    /// Kinematic surface sensible heat flux w'theta' (K m/s), put into the particles below
    /// `surface_layer`.
    pub surface_heat_flux: f64,
    /// Kinematic surface moisture flux w'q' (kg/kg m/s), likewise.
    pub surface_moisture_flux: f64,
    /// Depth of the surface layer that takes the surface fluxes (m); `null` = the kernel radius.
    pub surface_layer: Option<f64>,
    /// Levels by increasing height: radiation, moisture tendency and subsidence, linear between
    /// levels and constant below the first and above the last; empty = none of the three.
    pub profile: Vec<ForcingLevel>,
}
impl Default for ForcingConfig {
    fn default() -> Self {
        Self {
            surface_heat_flux: 0.0,
            surface_moisture_flux: 0.0,
            surface_layer: None,
            profile: Vec::new(),
        }
    }
}

/// One level of `physics.forcing.profile`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForcingLevel {
    /// Height above the ground (m).
    pub height: f64,
    /// Radiative heating (K/day; negative cools).
    #[serde(default)]
    pub radiation: f64,
    /// Large-scale moisture tendency (g/kg per day; negative dries).
    #[serde(default)]
    pub moisture: f64,
    /// Large-scale vertical velocity w_ls (m/s; negative = subsidence). It advects the
    /// horizontal-mean profiles, not the particles.
    #[serde(default)]
    pub subsidence: f64,
}

/// One level of the wind profile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindLevel {
    /// Height above the ground (m).
    pub height: f64,
    /// Wind speed (m/s).
    pub speed: f64,
    /// Heading the air moves towards (degrees in the ground plane, 0 = +x, 90 = +z).
    #[serde(default)]
    pub direction: f64,
}

/// `physics.thermodynamics`: the saturation of eq. 10 as the paper has it, or at the pressure of
/// the particle's height.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Thermodynamics {
    /// gamma = A exp(B / (T + C)) at every height (the paper's eq. 10).
    #[default]
    Paper,
    /// gamma = A exp(B / (T + C)) p0 / p(y): eq. 10's constants are Bolton's (1980) saturation
    /// mixing ratio at p0 = 1e5 Pa, and the mixing ratio of a given vapor pressure goes as 1 / p.
    /// p(y) is the hydrostatic pressure of the dry adiabatic reference atmosphere over the
    /// floor: p(y) = p_s (1 - Gamma_d y / T_s)^(c_p / R_d), with T_s the ground temperature,
    /// Gamma_d = g / c_p the adiabatic lapse rate and c_p / R_d = 3.5 (dry air).
    Atmospheric,
}
impl Thermodynamics {
    pub fn is_paper(&self) -> bool {
        *self == Thermodynamics::Paper
    }
}

/// The reference eq. 6's force is measured against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BuoyancyReference {
    /// kb (T - T0(y)) / T0(y) - kg w, as in the paper.
    Environment,
    /// The same, less its mass-weighted horizontal mean at the particle's height (from the
    /// state at the start of the frame). A force that depends on height alone is balanced by
    /// pressure in a closed incompressible box, so this changes no exact solution; it leaves
    /// the density solve only the horizontal differences to hold (heating under the whole
    /// ground otherwise lifts the bottom layer faster than the solve refills it).
    LayerMean,
}

/// How the walls take part in the temperature smoothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallHeat {
    /// No heat crosses the floor or the ceiling.
    Insulated,
    /// The wall particles hold the environment temperature of their wall.
    Fixed,
}

/// `physics.smoothing.vapor_mixing`: the pairs of neighbours between which vapor diffuses.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VaporMixing {
    /// Only pairs of which one particle holds cloud water: clear air (and the inversion over
    /// it) keeps its vapor, and mixing is the entrainment at a cloud's edge.
    #[default]
    CloudEdges,
    /// Every pair of fluid neighbours, as an LES's subgrid diffusion mixes its scalars
    /// everywhere: the moist air the surface flux makes mixes with the air around it as it
    /// rises, where with `cloud_edges` it keeps its vapor up to its condensation level.
    Everywhere,
}
impl VaporMixing {
    pub fn is_cloud_edges(&self) -> bool {
        *self == VaporMixing::CloudEdges
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SmoothingConfig {
    pub enabled: bool,
    /// Heat exchange with the floor and the ceiling.
    pub walls: WallHeat,
    /// kappa of eq. 17b: the fraction of the smoothing correction applied per
    /// `solver.reference_step` seconds of simulated time.
    pub kappa: f64,
    /// epsilon of eq. 13 (m^2).
    pub epsilon: f64,
    /// Jacobi iterations per substep; each applies its share of kappa.
    pub iterations: u32,
    /// Diffusivity D (m^2/s) of the vapor mixing between neighbouring particles that the same
    /// pass applies (entrainment at cloud edges); 0 = none, as in the paper.
    pub vapor_diffusivity: f64,
    /// Which pairs the vapor mixing acts on. Left out of the serialisation at its default, so
    /// earlier hashes are unchanged.
    #[serde(skip_serializing_if = "VaporMixing::is_cloud_edges")]
    pub vapor_mixing: VaporMixing,
    /// Eq. 17b as fluxes between pairs, which keep the heat (the paper's per-particle step
    /// does not). Left out of the serialisation when false, so earlier hashes are unchanged.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub conservative: bool,
}
impl Default for SmoothingConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            walls: WallHeat::Insulated,
            kappa: 0.1,
            epsilon: 1.0e-2,
            iterations: 1,
            vapor_diffusivity: 0.0,
            vapor_mixing: VaporMixing::CloudEdges,
            conservative: false,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveConfig {
    pub enabled: bool,
    pub max_level: u32,
    /// Shape energy E = kp (1 - exp(-kc w)), eq. 20.
    pub kp: f64,
    pub kc: f64,
    /// Split when E > split_threshold (alpha), merge when E < merge_threshold (beta).
    pub split_threshold: f64,
    pub merge_threshold: f64,
    /// Particle capacity as a multiple of the initial count.
    pub capacity_factor: f64,
    /// No split/merge product may come closer than this fraction of its kernel radius to others.
    pub min_distance: f64,
    /// Split children sit at +-split_offset * h_child from the parent (fraction of the
    /// child's kernel radius; 0.25 puts them one rest spacing apart at kernel_ratio 2).
    pub split_offset: f64,
}
impl Default for AdaptiveConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            max_level: 3,
            kp: 1.0,
            kc: 5000.0,
            split_threshold: 0.5,
            merge_threshold: 0.1,
            capacity_factor: 2.0,
            min_distance: 0.3,
            split_offset: 0.25,
        }
    }
}
impl AdaptiveConfig {
    /// Particle slots per particle of a run, defined here alone: `capacity_factor` when
    /// adaptive (split adds particles; its range starts at 1), else 1
    /// (`sim::footprint::ShotSize::capacity` rounds).
    pub fn slots_per_particle(&self) -> f64 {
        if self.enabled {
            self.capacity_factor
        } else {
            1.0
        }
    }
}

/// The `gpu` section: the device's own choice, defined where the device is opened.
pub use crate::gpu::choice::{Backend, GpuConfig};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExportConfig {
    /// Voxel edge (m). One transform for the whole shot.
    pub voxel_size: f64,
    /// Values below this stay inactive (background 0).
    pub threshold: f64,
    /// The density grid holds cloud water times this (1000: grams per kilogram of air, so a
    /// cumulus core reads about 0.5-2, what renderers expect of a density).
    pub density_scale: f64,
    /// Renderer preset (`export::profile`): up axis, velocity basis, vector class and aliases
    /// for that renderer. A key set here explicitly wins over the profile.
    pub profile: Option<Profile>,
    /// Metres per scene unit of the VDB files: divides the transform, the velocities and the
    /// lengths in their metadata (the simulation stays in metres).
    pub scale: f64,
    /// Up axis of the VDB files (the simulation is y-up); unset: the profile's, else `y`.
    pub up_axis: Option<UpAxis>,
    /// Time basis of the `vel` grid; unset: the profile's, else `playback`.
    pub velocity_time: Option<VelocityTime>,
    /// Write `particles/<shot>.<frame>.ply` per frame (what `nimbus export` re-splats).
    pub particles: bool,
    /// Procedural detail at the cloud's surface, evaluated in the particles' rest frame
    /// (`splat::detail`).
    pub detail: DetailConfig,
    /// The physical meaning of the density grid: what turns it into extinction
    /// (`export::optics`). Left out of the serialisation at its defaults, so the hashes and
    /// manifests of shots that do not set it are unchanged.
    #[serde(skip_serializing_if = "OpticsConfig::is_default")]
    pub optics: OpticsConfig,
    pub grids: GridNames,
    pub vdb: VdbConfig,
    pub exr: ExrConfig,
    /// Write `<shot>.usda`: a USD layer with one Volume whose OpenVDBAsset fields are the VDB
    /// sequence (`export::usd`). Left out of the serialisation when off.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub usd: bool,
    /// NanoVDB files beside the VDBs (`io::nanovdb`); `true` / `false` stand for `enabled`.
    /// Left out of the serialisation when at its default.
    #[serde(
        skip_serializing_if = "NanovdbConfig::is_default",
        deserialize_with = "nanovdb_shorthand"
    )]
    pub nanovdb: NanovdbConfig,
}
impl ExportConfig {
    /// The run carries rest positions (`sim::rest`): detail or a `rest` grid needs them.
    pub fn tracks_rest(&self) -> bool {
        self.detail.enabled || !self.grids.rest.is_empty()
    }
}
impl Default for ExportConfig {
    fn default() -> Self {
        Self {
            voxel_size: 20.0,
            threshold: 1.0e-3,
            density_scale: 1000.0,
            profile: None,
            scale: 1.0,
            up_axis: None,
            velocity_time: None,
            particles: false,
            detail: DetailConfig::default(),
            optics: OpticsConfig::default(),
            grids: GridNames::default(),
            vdb: VdbConfig::default(),
            exr: ExrConfig::default(),
            usd: false,
            nanovdb: NanovdbConfig::default(),
        }
    }
}

/// Grid names in the VDB; an empty name leaves that grid out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GridNames {
    pub density: String,
    pub temperature: String,
    pub vapor: String,
    pub velocity: String,
    /// Name of the rest-position vector grids (`<name>` and, with dual rest fields, `<name>2`);
    /// empty (the default) leaves them out.
    pub rest: String,
    /// OpenVDB class of the velocity grid; unset: the profile's, else `unknown`.
    pub velocity_class: Option<VectorClass>,
    /// Extra names for the same grids (e.g. `heat: temperature` for Blender).
    pub aliases: std::collections::BTreeMap<String, String>,
}
impl Default for GridNames {
    fn default() -> Self {
        Self {
            density: "density".into(),
            temperature: "temperature".into(),
            vapor: "vapor".into(),
            velocity: "vel".into(),
            rest: String::new(),
            velocity_class: None,
            aliases: Default::default(),
        }
    }
}

/// `export.optics`: the cloud's droplets and air, from which the density grid's extinction
/// follows (beta = 3 LWC / (2 rho_w r_e), docs/RENDERING.md "Physical optics").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OpticsConfig {
    /// Droplet effective radius r_e (micrometres): 5-15 in cumulus.
    pub effective_radius: f64,
    /// Air density (kg/m^3) that turns cloud water in kg/kg into liquid water content in kg/m^3.
    pub air_density: f64,
}
impl OpticsConfig {
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }
}
impl Default for OpticsConfig {
    fn default() -> Self {
        Self {
            effective_radius: 10.0,
            // the standard atmosphere at about 1 km, where cumulus grow
            air_density: 1.1,
        }
    }
}

/// `export.detail`: procedural noise finer than the particles, stuck to the flow.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetailConfig {
    pub enabled: bool,
    /// Wavelength of the first (largest) octave (m); unset: two particle spacings.
    pub scale: Option<f64>,
    /// Displacement of the cloud's surface by each octave, as a fraction of its wavelength.
    pub amplitude: f64,
    /// Octaves, each half the wavelength of the one before and half its weight.
    pub octaves: u32,
    pub character: DetailCharacter,
    /// Frames between two resets of each of the two rest fields (they alternate, half a period
    /// apart); 0: one rest field, never reset.
    pub rest_period: u32,
    /// Radius of the kernel that interpolates the rest displacement at a voxel, in units of
    /// the particle's own kernel radius (the density splat's): wider averages the particles'
    /// shuffle out of the rest coordinate.
    pub rest_smoothing: f64,
}
impl Default for DetailConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            scale: None,
            amplitude: 0.25,
            octaves: 3,
            character: DetailCharacter::Billowy,
            rest_period: 8,
            rest_smoothing: 1.5,
        }
    }
}

/// Shape of the detail noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DetailCharacter {
    /// Rounded puffs: |noise| (turbulence) per octave.
    Billowy,
    /// Thin strands: ridged noise (1 - |noise|)^2 per octave.
    Wispy,
}

/// Renderers with a preset of export conventions (`export::profile`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    Houdini,
    Blender,
    Arnold,
    Renderman,
    Karma,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    Y,
    Z,
}

/// What one unit of time is in the velocity grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityTime {
    /// Scene units per second of playback (frames at `output.fps`): v x frame_seconds x fps.
    Playback,
    /// Scene units per second of simulated time (the simulation's own m/s).
    Simulated,
    /// Scene units per frame: v x frame_seconds.
    PerFrame,
}

/// OpenVDB grid class written for the velocity grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VectorClass {
    Unknown,
    FogVolume,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VdbConfig {
    pub enabled: bool,
    pub compression: Compression,
    pub half: bool,
}
impl Default for VdbConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            compression: Compression::Blosc,
            half: false,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Compression {
    None,
    Zip,
    Blosc,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExrConfig {
    pub enabled: bool,
    pub half: bool,
}
impl Default for ExrConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            half: false,
        }
    }
}

/// `export.nanovdb`: `nvdb/<shot>.<frame>.nvdb` per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NanovdbConfig {
    pub enabled: bool,
    /// Storage of the float grids (quantised per leaf unless `float`); a vector grid is Vec3f
    /// and takes `float` only.
    pub precision: NanoPrecision,
    /// The grids to write: a list of names, or names with their own precision; empty (the
    /// default): every grid of the VDB files, aliases included.
    pub grids: NanoGrids,
    /// `fpn`: the largest error of a voxel, as a fraction of the grid's value range (max - min
    /// of its active values) in the frame.
    pub tolerance: f64,
}
impl Default for NanovdbConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            precision: NanoPrecision::Float,
            grids: NanoGrids::default(),
            tolerance: 1.0e-3,
        }
    }
}
impl NanovdbConfig {
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }
}

/// `export.nanovdb: true` is `export.nanovdb: {enabled: true}`.
fn nanovdb_shorthand<'de, D: serde::Deserializer<'de>>(d: D) -> Result<NanovdbConfig, D::Error> {
    struct V;
    impl<'de> serde::de::Visitor<'de> for V {
        type Value = NanovdbConfig;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("true, false or a mapping of keys (enabled, precision, grids, tolerance)")
        }
        fn visit_bool<E: serde::de::Error>(self, enabled: bool) -> Result<NanovdbConfig, E> {
            Ok(NanovdbConfig {
                enabled,
                ..NanovdbConfig::default()
            })
        }
        fn visit_unit<E: serde::de::Error>(self) -> Result<NanovdbConfig, E> {
            Ok(NanovdbConfig::default())
        }
        fn visit_map<A: serde::de::MapAccess<'de>>(
            self,
            map: A,
        ) -> Result<NanovdbConfig, A::Error> {
            NanovdbConfig::deserialize(serde::de::value::MapAccessDeserializer::new(map))
        }
    }
    d.deserialize_any(V)
}

/// How NanoVDB stores a float grid (NanoVDB 32.4's float, Fp4, Fp8, Fp16, FpN).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NanoPrecision {
    Float,
    Fp4,
    Fp8,
    Fp16,
    Fpn,
}
impl NanoPrecision {
    pub fn name(self) -> &'static str {
        match self {
            NanoPrecision::Float => "float",
            NanoPrecision::Fp4 => "fp4",
            NanoPrecision::Fp8 => "fp8",
            NanoPrecision::Fp16 => "fp16",
            NanoPrecision::Fpn => "fpn",
        }
    }
}

/// `export.nanovdb.grids`: `[density, vel]`, or `{density: fp8, vel: float}` (each grid with its
/// own precision); in file order of the VDB either way.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NanoGrids(pub Vec<(String, Option<NanoPrecision>)>);

impl Serialize for NanoGrids {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::{SerializeMap, SerializeSeq};
        if self.0.iter().any(|(_, p)| p.is_some()) {
            let mut m = s.serialize_map(Some(self.0.len()))?;
            for (name, p) in &self.0 {
                m.serialize_entry(name, &p.unwrap_or(NanoPrecision::Float))?;
            }
            m.end()
        } else {
            let mut q = s.serialize_seq(Some(self.0.len()))?;
            for (name, _) in &self.0 {
                q.serialize_element(name)?;
            }
            q.end()
        }
    }
}

impl<'de> Deserialize<'de> for NanoGrids {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = NanoGrids;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a list of grid names, or a mapping of grid names to precisions")
            }
            fn visit_unit<E: serde::de::Error>(self) -> Result<NanoGrids, E> {
                Ok(NanoGrids::default())
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<NanoGrids, A::Error> {
                let mut v = Vec::new();
                while let Some(name) = a.next_element::<String>()? {
                    v.push((name, None));
                }
                Ok(NanoGrids(v))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<NanoGrids, A::Error> {
                let mut v = Vec::new();
                while let Some((name, p)) = a.next_entry::<String, NanoPrecision>()? {
                    v.push((name, Some(p)));
                }
                Ok(NanoGrids(v))
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CheckpointConfig {
    /// Checkpoint every N frames (0 = only at the end and on interrupt).
    pub every: u32,
    /// Keep the newest K checkpoints.
    pub keep: u32,
}
impl Default for CheckpointConfig {
    fn default() -> Self {
        Self { every: 10, keep: 3 }
    }
}

impl OutputConfig {
    /// The substep of a frame of `substeps` substeps, frame_seconds / substeps (s), defined here
    /// alone (`output.substeps` gives the longest, which the config's checks bound).
    pub fn substep_dt(&self, substeps: u32) -> f64 {
        self.frame_seconds / substeps as f64
    }

    /// Frames simulated before `frames.start` and not written: `preroll` rounded up to whole
    /// frames of `frame_seconds` (a part frame would need a frame of another length).
    pub fn preroll_frames(&self) -> u32 {
        if !(self.preroll > 0.0 && self.frame_seconds > 0.0) {
            return 0;
        }
        let n = (self.preroll / self.frame_seconds * (1.0 - 1e-12)).ceil();
        n.clamp(0.0, u32::MAX as f64) as u32
    }
}

/// A field of levels sorted by increasing height at y: linear between levels, constant below
/// the first and above the last; 0 without levels.
pub fn piecewise_linear<L>(
    levels: &[L],
    y: f64,
    height: fn(&L) -> f64,
    field: fn(&L) -> f64,
) -> f64 {
    let (Some(first), Some(last)) = (levels.first(), levels.last()) else {
        return 0.0;
    };
    if y <= height(first) {
        return field(first);
    }
    if y >= height(last) {
        return field(last);
    }
    let k = levels.partition_point(|l| height(l) <= y);
    let (a, b) = (&levels[k - 1], &levels[k]);
    field(a) + (y - height(a)) / (height(b) - height(a)) * (field(b) - field(a))
}

impl EnvironmentConfig {
    /// A field of `profile` at height y: linear between levels, constant outside (the profile
    /// is not empty).
    pub fn profile_at(&self, y: f64, field: fn(&EnvironmentLevel) -> f64) -> f64 {
        piecewise_linear(&self.profile, y, |l| l.height, field)
    }

    /// The initial vapor (kg/kg) at height y when the profile gives it.
    pub fn profile_vapor(&self, y: f64) -> Option<f64> {
        let given = !self.profile.is_empty() && self.profile.iter().all(|l| l.vapor.is_some());
        given.then(|| self.profile_at(y, |l| l.vapor.unwrap_or(0.0)))
    }

    /// Lapse rate above the inversion.
    pub fn lapse_above(&self) -> f64 {
        self.lapse_rate_above.unwrap_or(self.lapse_rate)
    }
    /// Environment temperature T0(y) (K) for a ground temperature `ground` (K).
    /// Initial vapor at height y as a fraction of saturation: `ground` (`initial_vapor`) below
    /// the inversion, `humidity_above` above it, linear across the inversion layer.
    pub fn humidity(&self, ground: f64, y: f64) -> f64 {
        let (Some(base), Some(above)) = (self.inversion_height, self.humidity_above) else {
            return ground;
        };
        let f = if self.inversion_depth > 0.0 {
            ((y - base) / self.inversion_depth).clamp(0.0, 1.0)
        } else if y > base {
            1.0
        } else {
            0.0
        };
        ground + (above - ground) * f
    }

    pub fn temperature(&self, ground: f64, y: f64) -> f64 {
        if !self.profile.is_empty() {
            return self.profile_at(y, |l| l.temperature);
        }
        let Some(base) = self.inversion_height else {
            return ground - self.lapse_rate * y;
        };
        let below = y.min(base);
        let inside = (y - base).clamp(0.0, self.inversion_depth);
        let above = (y - base - self.inversion_depth).max(0.0);
        let rise = if self.inversion_depth > 0.0 {
            self.inversion_strength * inside / self.inversion_depth
        } else if y > base {
            self.inversion_strength
        } else {
            0.0
        };
        ground - self.lapse_rate * below + rise - self.lapse_above() * above
    }
}

impl HeatSource {
    /// The schedule's factor in [0, 1] at simulated time `t` (s).
    pub fn envelope(&self, t: f64) -> f64 {
        let smooth = |x: f64| {
            let x = x.clamp(0.0, 1.0);
            x * x * (3.0 - 2.0 * x)
        };
        let ramp = |d: f64| {
            if self.ramp > 0.0 {
                smooth(d / self.ramp)
            } else {
                (d >= 0.0) as u8 as f64
            }
        };
        let on = ramp(t - self.start);
        let off = self.end.map_or(1.0, |e| {
            if self.ramp > 0.0 {
                smooth((e - t) / self.ramp)
            } else {
                (t < e) as u8 as f64
            }
        });
        on * off
    }

    /// Fraction in [0, 1] of a disc's strength at ground point (x, z), with the shortest
    /// periodic distance `d` (x, z) from the centre: 1 inside 0.7 radius, a smoothstep to 0 at
    /// the radius.
    pub fn falloff(radius: f64, dx: f64, dz: f64) -> f64 {
        let r = (dx * dx + dz * dz).sqrt();
        let t = ((radius - r) / (0.3 * radius)).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }

    /// A disc on the ground at (x, z), always on, with no vapor.
    pub fn disc(x: f64, z: f64, radius: f64, strength: f64) -> Self {
        Self {
            shape: SourceShape::Disc,
            center: vec![x, z],
            radius: Some(radius),
            radii: None,
            size: None,
            angle: None,
            height: None,
            image: None,
            image_sha256: None,
            strength,
            vapor: None,
            start: 0.0,
            end: None,
            ramp: 0.0,
        }
    }

    /// Whether the shape lies on the ground (acts below `height`) rather than in the air.
    pub fn on_ground(&self) -> bool {
        match self.shape {
            SourceShape::Disc | SourceShape::Ellipse | SourceShape::Image => true,
            SourceShape::Sphere => false,
            SourceShape::Box => self.center.len() != 3,
        }
    }

    /// Vapor rate at full strength (kg/kg per s).
    pub fn vapor_rate(&self) -> f64 {
        self.vapor.unwrap_or(0.0)
    }
}

/// `control`: steering the cloud towards an artist's intent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct ControlConfig {
    /// Target-shape control (docs/CONFIG.md "control.target").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<TargetConfig>,
}

impl ControlConfig {
    pub fn is_unset(&self) -> bool {
        self.target.is_none()
    }

    /// The target when its control is on.
    pub fn active_target(&self) -> Option<&TargetConfig> {
        self.target.as_ref().filter(|t| t.enabled)
    }
}

/// A target volume the cloud is steered to fill (after Dobashi et al. 2008), a closed OBJ mesh
/// or a VDB fog volume or level set: per ground column the cloud top is compared with the
/// target's top and the heat and vapor supply of that column follows the gap (`sim::control`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetConfig {
    /// Whether the controller acts (the target is still loaded, checked and measured).
    #[serde(default = "d_true")]
    pub enabled: bool,
    /// Closed triangle or polygon mesh (Wavefront OBJ); a relative path is resolved against
    /// the config file's directory when the config is loaded. Exactly one of `mesh` and `vdb`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    /// SHA-256 of `mesh`, filled in when the config is loaded; a value given must match.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_sha256: Option<String>,
    /// OpenVDB file holding a float fog volume or level set (`sim::target_volume`); resolved
    /// like `mesh`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vdb: Option<String>,
    /// SHA-256 of `vdb`, filled in when the config is loaded; a value given must match.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vdb_sha256: Option<String>,
    /// The grid of `vdb` to use; `None` = the first float grid of class fog volume or level
    /// set, else the float grid named `density`, else the only float grid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<String>,
    /// Where the grid's value makes the inside: below `iso` for a level set (default 0), above
    /// it for any other class (default 0.01).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iso: Option<f64>,
    /// Scale of the target's own coordinates (the mesh's, or the VDB's world coordinates):
    /// one value (uniform) or three (x, y, z).
    #[serde(default = "d_unit_scale")]
    pub scale: Vec<f64>,
    /// Rotation about the vertical axis (degrees, from +x towards +z), after the scale.
    #[serde(default)]
    pub rotate_y: f64,
    /// Translation (m), after the rotation.
    #[serde(default)]
    pub translate: [f64; 3],
    /// Edge of the controller's voxels (m); `None` = the kernel radius h0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub voxel_size: Option<f64>,
    /// Cloud water (kg/kg, the mean over a voxel's particles) above which a voxel is cloud.
    #[serde(default = "d_cloud_threshold")]
    pub cloud_threshold: f64,
    /// Supply per metre of gap between the target's top and the cloud's top in a column
    /// (1/m): the column's supply factor is min(1, gain * gap).
    #[serde(default = "d_target_gain")]
    pub gain: f64,
    /// Heating at a supply factor of 1 (K/s), below `supply_height`.
    #[serde(default = "d_target_heat")]
    pub heat: f64,
    /// Vapor added at a supply factor of 1 (kg/kg per s), below `supply_height`.
    #[serde(default = "d_target_vapor")]
    pub vapor: f64,
    /// Top of the layer the supply heats (m); `None` = `physics.heat_height`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub supply_height: Option<f64>,
    /// Distance from the target's footprint (m) within which the other heating (noise,
    /// sources) keeps full strength; it falls to 0 over the next `margin` metres.
    #[serde(default = "d_target_margin")]
    pub margin: f64,
    /// Acceleration (m/s^2) pulling cloud particles (cloud water above `cloud_threshold`)
    /// outside the target towards its nearest voxel, within `reach` of it; 0 = no pull.
    #[serde(default)]
    pub pull: f64,
    /// Distance (m) from the target within which the pull acts.
    #[serde(default = "d_target_reach")]
    pub reach: f64,
}
fn d_target_reach() -> f64 {
    300.0
}
fn d_true() -> bool {
    true
}
fn d_unit_scale() -> Vec<f64> {
    vec![1.0]
}
fn d_cloud_threshold() -> f64 {
    1.0e-5
}
fn d_target_gain() -> f64 {
    0.01
}
fn d_target_heat() -> f64 {
    0.1
}
fn d_target_vapor() -> f64 {
    0.0
}
fn d_target_margin() -> f64 {
    100.0
}

impl TargetConfig {
    /// The scale along x, y, z.
    pub fn scale3(&self) -> [f64; 3] {
        match self.scale.as_slice() {
            [s] => [*s; 3],
            [x, y, z] => [*x, *y, *z],
            _ => [1.0; 3],
        }
    }
}
