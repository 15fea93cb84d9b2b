//! Range and consistency checks on a typed config. Each problem names the key to fix; `load`
//! adds the file position of that key. Comparisons are written so that NaN fails them.
use super::schema::*;

/// Initial particle count above which a shot is refused (GPU memory and run time).
pub const MAX_PARTICLES: f64 = 50.0e6;
/// Allocated capacity (initial count x adaptive.capacity_factor) above which a shot is refused.
pub const MAX_CAPACITY: f64 = 100.0e6;
/// Largest frame number: frame + 1 and frame counts stay far from u32 wrap, and every frame
/// number fits an i32 (renderers' frame type) and 10 digits of padding.
pub const MAX_FRAME: u32 = 999_999_999;
/// Longest shot name in bytes: `<shot>.<10 digits>.<ext>` stays under the 255-byte file-name
/// limit of common file systems.
pub const MAX_SHOT_BYTES: usize = 200;
/// Voxels per axis of the export grid above which a shot is refused.
pub const MAX_VOXELS_PER_AXIS: f64 = 65536.0;
/// Highest adaptive level (`ground::levels`, its one definition).
pub use crate::ground::levels::MAX_LEVEL;
/// Largest `min_distance` for which the 27 cells around a merging cell hold every particle the
/// adaptive stage's room check needs: |midpoint - x_i| < h_l / 2 <= 2^(-1/3) L / 2 and
/// h_new <= L.
pub const MAX_MIN_DISTANCE: f64 = 0.6;
/// Most entries of `physics.sources` (the thermo stage's uniform table; `ground::limits`).
pub use crate::ground::limits::MAX_SOURCES;
/// Longest grid name NanoVDB stores in the grid itself (255 bytes and a NUL; `io::nanovdb`).
pub const MAX_NANOVDB_NAME_BYTES: usize = 255;

/// The documented range of a number key: `lo`..`hi`, each end open or closed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloatRange {
    /// Key path; a list key's range applies to each element.
    pub key: &'static str,
    pub lo: f64,
    pub lo_open: bool,
    pub hi: f64,
    pub hi_open: bool,
}

const fn closed(key: &'static str, lo: f64, hi: f64) -> FloatRange {
    FloatRange {
        key,
        lo,
        lo_open: false,
        hi,
        hi_open: false,
    }
}
/// (lo, hi]
const fn above(key: &'static str, lo: f64, hi: f64) -> FloatRange {
    FloatRange {
        key,
        lo,
        lo_open: true,
        hi,
        hi_open: false,
    }
}
const fn open(key: &'static str, lo: f64, hi: f64) -> FloatRange {
    FloatRange {
        key,
        lo,
        lo_open: true,
        hi,
        hi_open: true,
    }
}

/// Range of every number key, as documented in docs/CONFIG.md (a test keeps the two in step).
/// The ends keep every derived quantity (dt, h0, kernel coefficients, masses) a normal f32.
pub const FLOAT_RANGES: &[FloatRange] = &[
    closed("output.fps", 1.0e-3, 1000.0),
    closed("output.frame_seconds", 1.0e-3, 3600.0),
    closed("output.preroll", 0.0, 1.0e7),
    closed("output.preview.sun_direction", -1.0e6, 1.0e6),
    closed("output.preview.sun_color", 0.0, 1000.0),
    closed("output.preview.sun_intensity", 0.0, 1000.0),
    above("output.preview.density_scale", 0.0, 1.0e6),
    closed("output.preview.camera.position", -1.0e7, 1.0e7),
    closed("output.preview.camera.look_at", -1.0e7, 1.0e7),
    open("output.preview.camera.fov_deg", 0.0, 180.0),
    above("domain.size", 0.0, 1.0e5),
    closed("domain.spacing", 0.01, 2000.0),
    above("domain.kernel_ratio", 1.0, 5.0),
    above("solver.rest_density", 0.0, 1.0e4),
    above("solver.relaxation", 0.0, 1000.0),
    closed("solver.scorr_k", 0.0, 1.0),
    open("solver.scorr_dq", 0.0, 1.0),
    closed("solver.xsph", 0.0, 1.0),
    closed("solver.vorticity", 0.0, 100.0),
    closed("solver.gravity", 0.0, 100.0),
    above("solver.max_speed", 0.0, 1000.0),
    closed("solver.expansion_tolerance", 0.0, 1.0),
    closed("solver.split_expansion_weight", 0.0, 1.0),
    closed("solver.reference_step", 1.0e-3, 3600.0),
    above("output.cfl", 0.0, 1.0),
    closed("physics.ground_temperature", 150.0, 400.0),
    closed("physics.environment.lapse_rate", -0.1, 0.1),
    closed("physics.environment.inversion_height", 0.0, 1.0e5),
    closed("physics.environment.inversion_depth", 0.0, 1.0e5),
    closed("physics.environment.inversion_strength", -100.0, 100.0),
    closed("physics.environment.lapse_rate_above", -0.1, 0.1),
    closed("physics.environment.humidity_above", 0.0, 2.0),
    closed("physics.environment.profile[].height", 0.0, 1.0e5),
    closed("physics.environment.profile[].temperature", 150.0, 400.0),
    closed("physics.environment.profile[].vapor", 0.0, 0.05),
    closed("physics.environment.perturbation.temperature", 0.0, 10.0),
    closed("physics.environment.perturbation.vapor", 0.0, 0.01),
    closed("physics.environment.perturbation.height", 0.0, 1.0e5),
    closed("physics.bowen_ratio", 0.05, 100.0),
    closed("physics.sources[].center", 0.0, 1.0e5),
    above("physics.sources[].radius", 0.0, 1.0e5),
    above("physics.sources[].radii", 0.0, 1.0e5),
    above("physics.sources[].size", 0.0, 1.0e5),
    closed("physics.sources[].angle", -360.0, 360.0),
    above("physics.sources[].height", 0.0, 1.0e5),
    closed("physics.sources[].strength", 0.0, 10.0),
    closed("physics.sources[].vapor", 0.0, 0.01),
    closed("physics.sources[].start", 0.0, 1.0e9),
    closed("physics.sources[].end", 0.0, 1.0e9),
    closed("physics.sources[].ramp", 0.0, 1.0e9),
    above("physics.wind.time_constant", 0.0, 1.0e6),
    closed("physics.wind.profile[].height", 0.0, 1.0e5),
    closed("physics.wind.profile[].speed", 0.0, 100.0),
    closed("physics.wind.profile[].direction", -360.0, 360.0),
    closed("physics.wind.initial[].height", 0.0, 1.0e5),
    closed("physics.wind.initial[].speed", 0.0, 100.0),
    closed("physics.wind.initial[].direction", -360.0, 360.0),
    closed("physics.wind.coriolis", -1.0e-3, 1.0e-3),
    closed("physics.wind.surface_friction", 0.0, 10.0),
    above("physics.wind.surface_layer", 0.0, 1.0e5),
    closed("physics.wind.ground_velocity", -100.0, 100.0),
    closed("physics.forcing.surface_heat_flux", -1.0, 1.0),
    closed("physics.forcing.surface_moisture_flux", -1.0e-3, 1.0e-3),
    above("physics.forcing.surface_layer", 0.0, 1.0e5),
    closed("physics.forcing.profile[].height", 0.0, 1.0e5),
    closed("physics.forcing.profile[].radiation", -100.0, 100.0),
    closed("physics.forcing.profile[].moisture", -100.0, 100.0),
    closed("physics.forcing.profile[].subsidence", -1.0, 1.0),
    closed("physics.adiabatic_lapse_rate", 0.0, 0.1),
    closed("physics.heat_source", 0.0, 10.0),
    closed("physics.heat_height", 0.0, 1.0e5),
    above("physics.heat_noise_scale", 0.0, 1.0e7),
    closed("physics.heat_noise_speed", 0.0, 100.0),
    above("physics.heat_noise_contrast", 0.0, 1000.0),
    closed("physics.buoyancy", 0.0, 100.0),
    closed("physics.cloud_weight", 0.0, 100.0),
    closed("physics.phase_rate", 0.0, 100.0),
    closed("physics.entrainment", 0.0, 0.1),
    closed("physics.surface_pressure", 1.0e4, 2.0e5),
    above("physics.saturation_a", 0.0, 1.0e8),
    closed("physics.saturation_b", -1.0e5, 1.0e5),
    closed("physics.saturation_c", -500.0, 500.0),
    closed("physics.latent_heat", 0.0, 1.0e4),
    closed("physics.initial_vapor", 0.0, 2.0),
    closed("physics.initial_speed", 0.0, 1000.0),
    above("physics.smoothing.kappa", 0.0, 1.0),
    above("physics.smoothing.epsilon", 0.0, 1.0e6),
    closed("physics.smoothing.vapor_diffusivity", 0.0, 1.0e4),
    above("adaptive.kp", 0.0, 1000.0),
    above("adaptive.kc", 0.0, 1.0e9),
    closed("adaptive.split_threshold", 0.0, 1000.0),
    closed("adaptive.merge_threshold", 0.0, 1000.0),
    closed("adaptive.capacity_factor", 1.0, 64.0),
    closed("adaptive.min_distance", 0.0, MAX_MIN_DISTANCE),
    above("adaptive.split_offset", 0.0, 0.5),
    above("export.voxel_size", 0.0, 1.0e5),
    closed("export.threshold", 0.0, 1.0e6),
    above("export.density_scale", 0.0, 1.0e9),
    closed("export.scale", 1.0e-6, 1.0e6),
    above("export.detail.scale", 0.0, 1.0e5),
    closed("export.detail.amplitude", 0.0, 1.0),
    closed("export.detail.rest_smoothing", 1.0, 4.0),
    closed("export.optics.effective_radius", 0.5, 1000.0),
    closed("export.optics.air_density", 0.01, 10.0),
    above("export.nanovdb.tolerance", 0.0, 1.0),
    above("control.target.scale", 0.0, 1.0e5),
    closed("control.target.rotate_y", -360.0, 360.0),
    closed("control.target.translate", -1.0e5, 1.0e5),
    above("control.target.voxel_size", 0.0, 1.0e5),
    closed("control.target.cloud_threshold", 0.0, 1.0),
    closed("control.target.gain", 0.0, 1000.0),
    closed("control.target.heat", 0.0, 10.0),
    closed("control.target.vapor", 0.0, 0.01),
    above("control.target.supply_height", 0.0, 1.0e5),
    closed("control.target.margin", 0.0, 1.0e5),
    closed("control.target.pull", 0.0, 100.0),
    closed("control.target.reach", 0.0, 1.0e5),
    closed("control.target.iso", -1.0e6, 1.0e6),
];

impl FloatRange {
    pub fn contains(&self, x: f64) -> bool {
        let lo_ok = if self.lo_open {
            x > self.lo
        } else {
            x >= self.lo
        };
        let hi_ok = if self.hi_open {
            x < self.hi
        } else {
            x <= self.hi
        };
        lo_ok && hi_ok
    }

    /// `[a, b]`, `(a, b]`, ... as docs/CONFIG.md writes it.
    pub fn text(&self) -> String {
        format!(
            "{}{}, {}{}",
            if self.lo_open { '(' } else { '[' },
            short(self.lo),
            short(self.hi),
            if self.hi_open { ')' } else { ']' }
        )
    }
}

/// 1000 as `1000`, 1e5 as `1e5`, 0.001 as `0.001`.
fn short(x: f64) -> String {
    if x != 0.0 && (x.abs() >= 1.0e4 || x.abs() < 1.0e-3) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// Every number key of `c` as (key path to report, range key, value).
pub fn float_values(c: &ShotConfig) -> Vec<(String, &'static str, f64)> {
    let mut v: Vec<(String, &'static str, f64)> = Vec::new();
    let mut one = |key: &'static str, x: f64| v.push((key.to_string(), key, x));
    let o = &c.output;
    let p = &o.preview;
    let ph = &c.physics;
    let s = &c.solver;
    let a = &c.adaptive;
    let e = &c.export;
    one("output.fps", o.fps);
    one("output.frame_seconds", o.frame_seconds);
    one("output.preroll", o.preroll);
    one("output.preview.sun_intensity", p.sun_intensity);
    one("output.preview.density_scale", p.density_scale);
    if let Some(cam) = &p.camera {
        one("output.preview.camera.fov_deg", cam.fov_deg);
    }
    one("domain.spacing", c.domain.spacing);
    one("domain.kernel_ratio", c.domain.kernel_ratio);
    for (key, x) in [
        ("solver.rest_density", s.rest_density),
        ("solver.relaxation", s.relaxation),
        ("solver.scorr_k", s.scorr_k),
        ("solver.scorr_dq", s.scorr_dq),
        ("solver.xsph", s.xsph),
        ("solver.vorticity", s.vorticity),
        ("solver.gravity", s.gravity),
        ("solver.max_speed", s.max_speed),
        ("solver.expansion_tolerance", s.expansion_tolerance),
        ("solver.split_expansion_weight", s.split_expansion_weight),
        ("solver.reference_step", s.reference_step),
        ("output.cfl", o.cfl),
        ("physics.ground_temperature", ph.ground_temperature),
        ("physics.environment.lapse_rate", ph.environment.lapse_rate),
        (
            "physics.environment.inversion_depth",
            ph.environment.inversion_depth,
        ),
        (
            "physics.environment.inversion_strength",
            ph.environment.inversion_strength,
        ),
        ("physics.adiabatic_lapse_rate", ph.adiabatic_lapse_rate),
        ("physics.heat_source", ph.heat_source),
        ("physics.heat_height", ph.heat_height),
        ("physics.heat_noise_scale", ph.heat_noise_scale),
        ("physics.heat_noise_speed", ph.heat_noise_speed),
        ("physics.heat_noise_contrast", ph.heat_noise_contrast),
        ("physics.buoyancy", ph.buoyancy),
        ("physics.cloud_weight", ph.cloud_weight),
        ("physics.phase_rate", ph.phase_rate),
        ("physics.entrainment", ph.entrainment),
        ("physics.saturation_a", ph.saturation_a),
        ("physics.saturation_b", ph.saturation_b),
        ("physics.saturation_c", ph.saturation_c),
        ("physics.latent_heat", ph.latent_heat),
        ("physics.initial_vapor", ph.initial_vapor),
        ("physics.initial_speed", ph.initial_speed),
        ("physics.smoothing.kappa", ph.smoothing.kappa),
        ("physics.smoothing.epsilon", ph.smoothing.epsilon),
        (
            "physics.smoothing.vapor_diffusivity",
            ph.smoothing.vapor_diffusivity,
        ),
        ("adaptive.kp", a.kp),
        ("adaptive.kc", a.kc),
        ("adaptive.split_threshold", a.split_threshold),
        ("adaptive.merge_threshold", a.merge_threshold),
        ("adaptive.capacity_factor", a.capacity_factor),
        ("adaptive.min_distance", a.min_distance),
        ("adaptive.split_offset", a.split_offset),
        ("export.voxel_size", e.voxel_size),
        ("export.threshold", e.threshold),
        ("export.density_scale", e.density_scale),
        ("export.scale", e.scale),
        ("export.detail.amplitude", e.detail.amplitude),
        ("export.detail.rest_smoothing", e.detail.rest_smoothing),
        ("export.optics.effective_radius", e.optics.effective_radius),
        ("export.optics.air_density", e.optics.air_density),
        ("export.nanovdb.tolerance", e.nanovdb.tolerance),
    ] {
        one(key, x);
    }
    let mut each = |key: &'static str, xs: &[f64]| {
        for (i, x) in xs.iter().enumerate() {
            v.push((format!("{key}[{i}]"), key, *x));
        }
    };
    each("output.preview.sun_direction", &p.sun_direction);
    each("output.preview.sun_color", &p.sun_color);
    if let Some(cam) = &p.camera {
        each("output.preview.camera.position", &cam.position);
        each("output.preview.camera.look_at", &cam.look_at);
    }
    each("domain.size", &c.domain.size);
    let env = &ph.environment;
    for (key, x) in [
        ("physics.environment.inversion_height", env.inversion_height),
        ("physics.environment.lapse_rate_above", env.lapse_rate_above),
        ("physics.environment.humidity_above", env.humidity_above),
        ("physics.bowen_ratio", ph.bowen_ratio),
        ("physics.surface_pressure", ph.surface_pressure),
        ("export.detail.scale", c.export.detail.scale),
    ] {
        if let Some(x) = x {
            v.push((key.to_string(), key, x));
        }
    }
    for (i, src) in ph.sources.iter().enumerate() {
        let mut field = |name: &str, key: &'static str, x: f64| {
            v.push((format!("physics.sources[{i}].{name}"), key, x));
        };
        field("strength", "physics.sources[].strength", src.strength);
        field("start", "physics.sources[].start", src.start);
        field("ramp", "physics.sources[].ramp", src.ramp);
        for (name, key, x) in [
            ("radius", "physics.sources[].radius", src.radius),
            ("angle", "physics.sources[].angle", src.angle),
            ("height", "physics.sources[].height", src.height),
            ("vapor", "physics.sources[].vapor", src.vapor),
            ("end", "physics.sources[].end", src.end),
        ] {
            if let Some(x) = x {
                field(name, key, x);
            }
        }
        let lists: [(&str, &'static str, &[f64]); 3] = [
            ("center", "physics.sources[].center", &src.center),
            (
                "radii",
                "physics.sources[].radii",
                src.radii.as_ref().map_or(&[], |r| r.as_slice()),
            ),
            (
                "size",
                "physics.sources[].size",
                src.size.as_deref().unwrap_or(&[]),
            ),
        ];
        for (name, key, xs) in lists {
            for (a, x) in xs.iter().enumerate() {
                v.push((format!("physics.sources[{i}].{name}[{a}]"), key, *x));
            }
        }
    }
    if let Some(t) = &c.control.target {
        for (key, x) in [
            ("control.target.rotate_y", t.rotate_y),
            ("control.target.cloud_threshold", t.cloud_threshold),
            ("control.target.gain", t.gain),
            ("control.target.heat", t.heat),
            ("control.target.vapor", t.vapor),
            ("control.target.margin", t.margin),
            ("control.target.pull", t.pull),
            ("control.target.reach", t.reach),
        ] {
            v.push((key.to_string(), key, x));
        }
        for (key, x) in [
            ("control.target.voxel_size", t.voxel_size),
            ("control.target.supply_height", t.supply_height),
            ("control.target.iso", t.iso),
        ] {
            if let Some(x) = x {
                v.push((key.to_string(), key, x));
            }
        }
        for (name, xs) in [
            ("scale", t.scale.as_slice()),
            ("translate", &t.translate[..]),
        ] {
            let key = if name == "scale" {
                "control.target.scale"
            } else {
                "control.target.translate"
            };
            for (a, x) in xs.iter().enumerate() {
                v.push((format!("control.target.{name}[{a}]"), key, *x));
            }
        }
    }
    if let Some(w) = &ph.wind {
        v.push((
            "physics.wind.time_constant".into(),
            "physics.wind.time_constant",
            w.time_constant,
        ));
        if let Some(f) = w.coriolis {
            v.push(("physics.wind.coriolis".into(), "physics.wind.coriolis", f));
        }
        v.push((
            "physics.wind.surface_friction".into(),
            "physics.wind.surface_friction",
            w.surface_friction,
        ));
        if let Some(d) = w.surface_layer {
            v.push((
                "physics.wind.surface_layer".into(),
                "physics.wind.surface_layer",
                d,
            ));
        }
        for (a, x) in w.ground_velocity.iter().enumerate() {
            v.push((
                format!("physics.wind.ground_velocity[{a}]"),
                "physics.wind.ground_velocity",
                *x,
            ));
        }
        for (list, levels, keys) in [
            (
                "profile",
                &w.profile,
                [
                    "physics.wind.profile[].height",
                    "physics.wind.profile[].speed",
                    "physics.wind.profile[].direction",
                ],
            ),
            (
                "initial",
                &w.initial,
                [
                    "physics.wind.initial[].height",
                    "physics.wind.initial[].speed",
                    "physics.wind.initial[].direction",
                ],
            ),
        ] {
            for (k, l) in levels.iter().enumerate() {
                for (j, (name, x)) in [
                    ("height", l.height),
                    ("speed", l.speed),
                    ("direction", l.direction),
                ]
                .into_iter()
                .enumerate()
                {
                    v.push((format!("physics.wind.{list}[{k}].{name}"), keys[j], x));
                }
            }
        }
    }
    for (k, l) in ph.environment.profile.iter().enumerate() {
        let at = |f: &str| format!("physics.environment.profile[{k}].{f}");
        v.push((
            at("height"),
            "physics.environment.profile[].height",
            l.height,
        ));
        let t = "physics.environment.profile[].temperature";
        v.push((at("temperature"), t, l.temperature));
        if let Some(q) = l.vapor {
            v.push((at("vapor"), "physics.environment.profile[].vapor", q));
        }
    }
    if let Some(pt) = &ph.environment.perturbation {
        for (key, x) in [
            (
                "physics.environment.perturbation.temperature",
                pt.temperature,
            ),
            ("physics.environment.perturbation.vapor", pt.vapor),
            ("physics.environment.perturbation.height", pt.height),
        ] {
            v.push((key.to_string(), key, x));
        }
    }
    if let Some(f) = &ph.forcing {
        let mut put = |key: &'static str, x: f64| v.push((key.to_string(), key, x));
        put("physics.forcing.surface_heat_flux", f.surface_heat_flux);
        put(
            "physics.forcing.surface_moisture_flux",
            f.surface_moisture_flux,
        );
        if let Some(d) = f.surface_layer {
            put("physics.forcing.surface_layer", d);
        }
        for (k, l) in f.profile.iter().enumerate() {
            for (name, key, x) in [
                ("height", "physics.forcing.profile[].height", l.height),
                (
                    "radiation",
                    "physics.forcing.profile[].radiation",
                    l.radiation,
                ),
                ("moisture", "physics.forcing.profile[].moisture", l.moisture),
                (
                    "subsidence",
                    "physics.forcing.profile[].subsidence",
                    l.subsidence,
                ),
            ] {
                v.push((format!("physics.forcing.profile[{k}].{name}"), key, x));
            }
        }
    }
    v
}

fn check_ranges(k: &mut Checks, c: &ShotConfig) {
    for (key, range_key, x) in float_values(c) {
        let Some(r) = FLOAT_RANGES.iter().find(|r| r.key == range_key) else {
            k.fail(&[key.as_str()], "internal: no documented range".into());
            continue;
        };
        if k.finite(&key, x) && !r.contains(x) {
            k.fail(
                &[key.as_str()],
                format!("expected a number in {}, got {}", r.text(), num(x)),
            );
        }
    }
}

/// One problem: the keys it concerns (the first one present in the file is reported) and what
/// is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct Issue {
    pub keys: Vec<String>,
    pub msg: String,
}

struct Checks {
    issues: Vec<Issue>,
}

fn num(x: f64) -> String {
    super::node::fmt_float(x)
}

impl Checks {
    fn fail(&mut self, keys: &[&str], msg: String) {
        self.issues.push(Issue {
            keys: keys.iter().map(|k| k.to_string()).collect(),
            msg,
        });
    }
    fn finite(&mut self, key: &str, x: f64) -> bool {
        if x.is_finite() {
            true
        } else {
            self.fail(&[key], format!("expected a finite number, got {}", num(x)));
            false
        }
    }
    fn uint_within(&mut self, key: &str, x: u32, lo: u32, hi: u32) {
        if !(lo..=hi).contains(&x) {
            self.fail(
                &[key],
                format!("expected an integer from {lo} to {hi}, got {x}"),
            );
        }
    }
}

/// Digits needed to print `n` in decimal.
fn digits(n: u32) -> u32 {
    n.checked_ilog10().unwrap_or(0) + 1
}

/// Initial lattice particle count: round(size/spacing), at least 1, per axis (what
/// `DomainConfig::lattice` seeds; a unit test keeps the two equal).
pub fn lattice_count(d: &DomainConfig) -> f64 {
    d.size
        .iter()
        .map(|s| (s / d.spacing).round().max(1.0))
        .product()
}

pub(crate) fn issues(c: &ShotConfig) -> Vec<Issue> {
    let mut k = Checks { issues: Vec::new() };
    check_ranges(&mut k, c);
    if !k.issues.is_empty() {
        return k.issues; // the consistency checks below need values in range
    }
    check_names(&mut k, c);
    check_output(&mut k, &c.output, &c.physics.sources);
    check_domain(&mut k, c);
    check_solver(&mut k, &c.solver, c);
    check_physics(&mut k, &c.physics, c);
    check_adaptive(&mut k, &c.adaptive, c);
    check_export(&mut k, &c.export, &c.domain);
    check_handoff(&mut k, &c.export);
    // control.target: one shape and the scale's form (config::art; the shape itself is read
    // and placed by the prepared shot, shot::target)
    k.issues.extend(super::art::target_issues(c));
    if c.gpu.adapter.trim().is_empty() {
        k.fail(
            &["gpu.adapter"],
            "expected \"auto\" or part of an adapter name, got an empty string".into(),
        );
    }
    if c.checkpoint.keep == 0 {
        k.fail(
            &["checkpoint.keep"],
            "expected at least 1 (the newest checkpoint is always kept), got 0".into(),
        );
    }
    k.issues
}

fn check_names(k: &mut Checks, c: &ShotConfig) {
    let s = &c.shot;
    if s.trim().is_empty() {
        k.fail(
            &["shot"],
            "expected a shot name, got an empty string".into(),
        );
    } else if s == "."
        || s == ".."
        || s.chars()
            .any(|ch| "/\\:*?\"<>|".contains(ch) || ch.is_control())
    {
        k.fail(
            &["shot"],
            format!(
                "the shot name prefixes every output file: use letters, digits, '-', '_' or '.', got {:?}",
                super::node::clip(s)
            ),
        );
    }
    if s.len() > MAX_SHOT_BYTES {
        k.fail(
            &["shot"],
            format!(
                "the shot name prefixes every output file name: at most {MAX_SHOT_BYTES} bytes, got {}",
                s.len()
            ),
        );
    }
    if c.output.dir.trim().is_empty() {
        k.fail(
            &["output.dir"],
            "expected a directory, got an empty string".into(),
        );
    }
}

fn check_output(k: &mut Checks, o: &OutputConfig, sources: &[HeatSource]) {
    if o.preview.source_overlay && sources.is_empty() {
        k.fail(
            &["output.preview.source_overlay"],
            "the overlay draws physics.sources, and the shot has none".into(),
        );
    }
    if o.preview.movie && !o.preview.enabled {
        k.fail(
            &["output.preview.movie"],
            "the movie is made of the previews: set output.preview.enabled: true too".into(),
        );
    }
    for (key, f) in [
        ("output.frames.start", o.frames.start),
        ("output.frames.end", o.frames.end),
    ] {
        if f > MAX_FRAME {
            k.fail(
                &[key],
                format!("expected a frame number from 0 to {MAX_FRAME}, got {f}"),
            );
        }
    }
    if o.frames.end < o.frames.start {
        k.fail(
            &["output.frames.end", "output.frames.start"],
            format!(
                "end frame {} is before start frame {}",
                o.frames.end, o.frames.start
            ),
        );
    }
    k.uint_within("output.substeps", o.substeps, 1, 1000);
    k.uint_within("output.max_substeps", o.max_substeps, 1, 1000);
    if o.max_substeps < o.substeps {
        k.fail(
            &["output.max_substeps", "output.substeps"],
            format!(
                "max_substeps ({}) is below substeps ({}), the fewest substeps per frame",
                o.max_substeps, o.substeps
            ),
        );
    }
    if o.preroll.is_finite()
        && o.frame_seconds > 0.0
        && o.preroll / o.frame_seconds > MAX_PREROLL_FRAMES as f64
    {
        k.fail(
            &["output.preroll", "output.frame_seconds"],
            format!(
                "{} s of pre-roll is more than {MAX_PREROLL_FRAMES} frames of {} s",
                o.preroll, o.frame_seconds
            ),
        );
    }
    k.uint_within("output.frame_padding", o.frame_padding, 1, 10);
    if (1..=10).contains(&o.frame_padding) && digits(o.frames.end) > o.frame_padding {
        k.fail(
            &["output.frame_padding", "output.frames.end"],
            format!(
                "{} digits cannot hold end frame {} (needs {}); file names would not sort",
                o.frame_padding,
                o.frames.end,
                digits(o.frames.end)
            ),
        );
    }
    let p = &o.preview;
    for (i, r) in p.resolution.iter().enumerate() {
        k.uint_within(&format!("output.preview.resolution[{i}]"), *r, 1, 16384);
    }
    let len2: f64 = p.sun_direction.iter().map(|x| x * x).sum();
    if p.sun_direction.iter().all(|x| x.is_finite()) && len2 <= 1e-24 {
        k.fail(
            &["output.preview.sun_direction"],
            "expected a non-zero direction, got [0, 0, 0]".into(),
        );
    }
    if let Some(cam) = &p.camera {
        if cam.position == cam.look_at {
            k.fail(
                &["output.preview.camera.look_at"],
                "the camera looks at its own position; move look_at away from position".into(),
            );
        }
    }
}

/// Most frames a pre-roll may take (`output.preroll` / `output.frame_seconds`).
pub const MAX_PREROLL_FRAMES: u32 = 1_000_000;

const AXES: [&str; 3] = ["x", "y", "z"];

fn check_domain(k: &mut Checks, c: &ShotConfig) {
    let d = &c.domain;
    let before = k.issues.len();
    for (i, a) in d.periodic.iter().enumerate() {
        if d.periodic[..i].contains(a) {
            k.fail(
                &[format!("domain.periodic[{i}]").as_str()],
                format!("axis {} is listed twice", axis_name(*a)),
            );
        }
    }
    if k.issues.len() > before {
        return; // the derived checks below need sane inputs
    }
    let h0 = d.kernel_radius();
    for (i, axis) in AXES.iter().enumerate() {
        if h0 > d.size[i] {
            k.fail(
                &["domain.spacing", "domain.kernel_ratio"],
                format!(
                    "kernel radius h0 = spacing * kernel_ratio = {} m is larger than the domain along {} ({} m)",
                    num(h0),
                    axis,
                    num(d.size[i])
                ),
            );
            return;
        }
    }
    for a in &d.periodic {
        let i = match a {
            Axis::X => 0,
            Axis::Z => 2,
        };
        let cells = d.size[i] / h0;
        if cells < 3.0 {
            k.fail(
                &["domain.periodic", "domain.size"],
                format!(
                    "periodic axis {} needs at least 3 kernel-radius cells (size/h0 >= 3), got {:.2} (size {} m, h0 {} m)",
                    AXES[i],
                    cells,
                    num(d.size[i]),
                    num(h0)
                ),
            );
        }
    }
    let n = lattice_count(d);
    if n > MAX_PARTICLES {
        k.fail(
            &["domain.spacing", "domain.size"],
            format!(
                "{:.1} million particles (size/spacing per axis) exceeds the limit of {:.0} million; increase the spacing",
                n / 1e6,
                MAX_PARTICLES / 1e6
            ),
        );
    }
}

fn axis_name(a: Axis) -> &'static str {
    match a {
        Axis::X => "x",
        Axis::Z => "z",
    }
}

fn check_solver(k: &mut Checks, s: &SolverConfig, c: &ShotConfig) {
    k.uint_within("solver.iterations", s.iterations, 1, 100);
    if s.min_iterations < 1 || s.min_iterations > s.iterations {
        k.fail(
            &["solver.min_iterations"],
            format!(
                "expected an integer from 1 to solver.iterations ({}), got {}",
                s.iterations, s.min_iterations
            ),
        );
    }
    k.uint_within("solver.scorr_n", s.scorr_n, 1, 16);
    if s.max_speed.is_finite() && c.physics.initial_speed > s.max_speed {
        k.fail(
            &["physics.initial_speed", "solver.max_speed"],
            format!(
                "initial speed {} m/s is above solver.max_speed {} m/s",
                num(c.physics.initial_speed),
                num(s.max_speed)
            ),
        );
    }
}

fn check_physics(k: &mut Checks, p: &PhysicsConfig, c: &ShotConfig) {
    let env = &p.environment;
    if p.sources.len() > MAX_SOURCES {
        k.fail(
            &["physics.sources"],
            format!(
                "{} sources; at most {} are supported",
                p.sources.len(),
                MAX_SOURCES
            ),
        );
    }
    // shapes, schedules and the wind profile (config::art; heat maps: shot::assets)
    k.issues.extend(super::art::issues(p, c));
    if p.bowen_ratio.is_some() && p.latent_heat <= 0.0 {
        k.fail(
            &["physics.bowen_ratio"],
            "sets the evaporation against the latent heat: physics.latent_heat must be above 0"
                .to_string(),
        );
    }
    if p.surface_pressure.is_some() && p.thermodynamics.is_paper() {
        k.fail(
            &["physics.surface_pressure"],
            "is read only with physics.thermodynamics: atmospheric".to_string(),
        );
    }
    // the reference atmosphere's pressure reaches 0 at T_s / Gamma_d (about 30 km)
    if !p.thermodynamics.is_paper() && p.adiabatic_lapse_rate > 0.0 {
        let top = p.ground_temperature / p.adiabatic_lapse_rate;
        let height = c.domain.size[1];
        if height.is_finite() && top.is_finite() && height >= 0.5 * top {
            k.fail(
                &["physics.thermodynamics", "domain.size"],
                format!(
                    "the domain is {} m high; with atmospheric thermodynamics it must stay below half the height of the reference atmosphere, ground_temperature / adiabatic_lapse_rate / 2 = {} m",
                    num(height),
                    num(0.5 * top)
                ),
            );
        }
    }
    if p.virtual_temperature && p.buoyancy_reference != crate::config::BuoyancyReference::LayerMean
    {
        k.fail(
            &["physics.virtual_temperature", "physics.buoyancy_reference"],
            "measures buoyancy against the horizontal mean: set physics.buoyancy_reference: layer_mean too (the environment has no virtual temperature of its own)"
                .to_string(),
        );
    }
    if env.humidity_above.is_some() && env.inversion_height.is_none() {
        k.fail(
            &["physics.environment.humidity_above"],
            "is the humidity above the inversion: set physics.environment.inversion_height too"
                .to_string(),
        );
    }
    let sm = &p.smoothing;
    k.uint_within("physics.smoothing.iterations", sm.iterations, 1, 100);
    if sm.vapor_mixing == crate::config::VaporMixing::Everywhere && sm.vapor_diffusivity == 0.0 {
        k.fail(
            &["physics.smoothing.vapor_mixing"],
            "says which pairs the vapor mixing acts on, and physics.smoothing.vapor_diffusivity is 0: set it too".to_string(),
        );
    }

    // The environment must stay above absolute zero and above -C (eq. 10 divides by T + C).
    let height = c.domain.size[1];
    let mut coldest = p.ground_temperature;
    let mut marks = vec![height];
    if let Some(h) = env.inversion_height {
        marks.extend([h, h + env.inversion_depth]);
    }
    marks.extend(env.profile.iter().map(|l| l.height));
    for y in marks.into_iter().filter(|&y| y <= height) {
        coldest = coldest.min(env.temperature(p.ground_temperature, y));
    }
    if coldest.is_finite() && height.is_finite() && height > 0.0 {
        if coldest <= 0.0 {
            k.fail(
                &["physics.environment.lapse_rate", "physics.ground_temperature"],
                format!(
                    "the environment reaches {} K at the top of the domain ({} m); it must stay above 0 K",
                    num(coldest),
                    num(height)
                ),
            );
        } else if p.saturation_c.is_finite() && coldest + p.saturation_c <= 0.0 {
            k.fail(
                &["physics.saturation_c"],
                format!(
                    "T + C must stay > 0 in eq. 10, but the coldest environment temperature is {} K and C = {}",
                    num(coldest),
                    num(p.saturation_c)
                ),
            );
        }
    }
    // eq. 9 is integrated explicitly: alpha * dt > 1 overshoots saturation.
    if c.output.substeps > 0 && c.output.frame_seconds > 0.0 {
        let dt = c.output.substep_dt(c.output.substeps);
        if p.phase_rate.is_finite() && p.phase_rate * dt > 1.0 {
            k.fail(
                &["physics.phase_rate", "output.substeps"],
                format!(
                    "phase_rate * substep dt = {} * {} s = {} > 1 makes eq. 9 overshoot; raise output.substeps or lower physics.phase_rate",
                    num(p.phase_rate),
                    num(dt),
                    num(p.phase_rate * dt)
                ),
            );
        }
    }
}

fn check_adaptive(k: &mut Checks, a: &AdaptiveConfig, c: &ShotConfig) {
    k.uint_within("adaptive.max_level", a.max_level, 0, MAX_LEVEL);
    if a.merge_threshold.is_finite()
        && a.split_threshold.is_finite()
        && a.merge_threshold >= a.split_threshold
    {
        k.fail(
            &["adaptive.merge_threshold", "adaptive.split_threshold"],
            format!(
                "merge_threshold ({}) must be below split_threshold ({}), or particles would split and merge back forever",
                num(a.merge_threshold),
                num(a.split_threshold)
            ),
        );
    }
    if a.enabled && a.kp.is_finite() && a.split_threshold >= a.kp {
        k.fail(
            &["adaptive.split_threshold", "adaptive.kp"],
            format!(
                "split_threshold ({}) is at or above kp ({}); E = kp(1 - exp(-kc w)) stays below kp (eq. 20), so nothing would split",
                num(a.split_threshold),
                num(a.kp)
            ),
        );
    }
    if a.enabled && a.capacity_factor.is_finite() {
        let cap = lattice_count(&c.domain) * a.slots_per_particle();
        if cap > MAX_CAPACITY && lattice_count(&c.domain) <= MAX_PARTICLES {
            k.fail(
                &["adaptive.capacity_factor"],
                format!(
                    "capacity of {:.1} million particles exceeds the limit of {:.0} million",
                    cap / 1e6,
                    MAX_CAPACITY / 1e6
                ),
            );
        }
    }
}

fn check_export(k: &mut Checks, e: &ExportConfig, d: &DomainConfig) {
    if e.voxel_size.is_finite() && e.voxel_size > 0.0 {
        for (i, axis) in AXES.iter().enumerate() {
            let n = d.size[i] / e.voxel_size;
            if n > MAX_VOXELS_PER_AXIS {
                k.fail(
                    &["export.voxel_size"],
                    format!(
                        "{:.0} voxels along {} exceeds {}; increase the voxel size",
                        n, axis, MAX_VOXELS_PER_AXIS
                    ),
                );
                break;
            }
        }
    }
    let g = &e.grids;
    let named = [
        ("export.grids.density", &g.density),
        ("export.grids.temperature", &g.temperature),
        ("export.grids.vapor", &g.vapor),
        ("export.grids.velocity", &g.velocity),
        ("export.grids.rest", &g.rest),
    ];
    k.uint_within("export.detail.octaves", e.detail.octaves, 1, 8);
    k.uint_within(
        "export.detail.rest_period",
        e.detail.rest_period,
        0,
        crate::config::MAX_FRAME,
    );
    if !g.rest.is_empty() && e.detail.rest_period > 0 {
        let second = format!("{}2", g.rest);
        if let Some((other, _)) = named.iter().find(|(_, n)| **n == second) {
            k.fail(
                &["export.grids.rest"],
                format!(
                    "the second rest grid {second:?} (dual rest fields) is also used by {other}"
                ),
            );
        }
    }
    for (i, (key, name)) in named.iter().enumerate() {
        if name.is_empty() {
            continue;
        }
        if name.trim() != name.as_str() || name.chars().any(char::is_control) {
            k.fail(
                &[*key],
                format!("grid names may not start or end with spaces, got {name:?}"),
            );
        }
        if let Some((other, _)) = named[..i].iter().find(|(_, n)| n == name) {
            k.fail(
                &[*key],
                format!("grid name {name:?} is also used by {other}"),
            );
        }
    }
    if e.vdb.enabled && named.iter().all(|(_, n)| n.is_empty()) {
        k.fail(
            &["export.grids"],
            "every grid name is empty, so the VDB files would hold no grid; name one or set export.vdb.enabled: false".into(),
        );
    }
    for (alias, target) in &g.aliases {
        let key = format!("export.grids.aliases.{alias}");
        if alias.trim().is_empty() {
            k.fail(&["export.grids.aliases"], "an alias name is empty".into());
        } else if named.iter().any(|(_, n)| *n == alias) {
            k.fail(
                &[key.as_str()],
                format!("alias {alias:?} clashes with a grid of that name"),
            );
        } else if target.is_empty() || !named.iter().any(|(_, n)| *n == target) {
            let valid: Vec<&str> = named
                .iter()
                .filter(|(_, n)| !n.is_empty())
                .map(|(_, n)| n.as_str())
                .collect();
            k.fail(
                &[key.as_str()],
                format!(
                    "alias target {target:?} is not a grid name (grids: {})",
                    valid.join(", ")
                ),
            );
        }
    }
}

/// `export.usd`: the layer needs the VDB files it points at. (NanoVDB's grids are checked with
/// the prepared shot, `shot::handoff`, which knows the VDB files' grids.)
fn check_handoff(k: &mut Checks, e: &ExportConfig) {
    if e.usd && !e.vdb.enabled {
        k.fail(
            &["export.usd"],
            "the USD layer's fields point at the VDB files, and export.vdb.enabled is false: enable the VDB files or set export.usd: false".into(),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> ShotConfig {
        super::super::read_str(
            "shot: t\noutput: {frames: {start: 1, end: 10}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
            "t.yaml",
            &[],
        )
        .unwrap()
        .config
    }

    fn first_key(c: &ShotConfig) -> Option<String> {
        issues(c).first().map(|i| i.keys[0].clone())
    }

    #[test]
    fn base_is_valid() {
        assert_eq!(issues(&base()), vec![]);
    }

    #[test]
    fn each_rule_names_its_key() {
        type Edit = fn(&mut ShotConfig);
        let cases: Vec<(Edit, &str)> = vec![
            (|c| c.output.frames.end = 0, "output.frames.end"),
            (|c| c.output.substeps = 0, "output.substeps"),
            (|c| c.domain.spacing = 0.0, "domain.spacing"),
            (|c| c.domain.spacing = -1.0, "domain.spacing"),
            (|c| c.domain.spacing = f64::NAN, "domain.spacing"),
            (|c| c.domain.kernel_ratio = 30.0, "domain.kernel_ratio"),
            (|c| c.domain.size = [100.0, 8.0, 100.0], "domain.spacing"),
            (|c| c.domain.size = [25.0, 50.0, 100.0], "domain.periodic"),
            (
                |c| c.domain.periodic = vec![Axis::X, Axis::X],
                "domain.periodic[1]",
            ),
            (|c| c.domain.spacing = 0.01, "domain.spacing"),
            (|c| c.export.voxel_size = 0.0, "export.voxel_size"),
            (
                |c| c.physics.smoothing.kappa = 0.0,
                "physics.smoothing.kappa",
            ),
            (
                |c| c.physics.smoothing.kappa = 1.5,
                "physics.smoothing.kappa",
            ),
            (
                |c| c.physics.smoothing.vapor_diffusivity = -1.0,
                "physics.smoothing.vapor_diffusivity",
            ),
            (
                |c| c.physics.environment.humidity_above = Some(0.3),
                "physics.environment.humidity_above",
            ),
            (
                |c| c.physics.smoothing.vapor_mixing = crate::config::VaporMixing::Everywhere,
                "physics.smoothing.vapor_mixing",
            ),
            (|c| c.physics.bowen_ratio = Some(0.0), "physics.bowen_ratio"),
            (
                |c| c.physics.surface_pressure = Some(101_500.0),
                "physics.surface_pressure",
            ),
            (
                |c| {
                    let level = |height, vapor| EnvironmentLevel {
                        height,
                        temperature: 290.0,
                        vapor,
                    };
                    c.physics.environment.profile =
                        vec![level(0.0, Some(0.01)), level(500.0, None)];
                },
                "physics.environment.profile[1]",
            ),
            (
                |c| {
                    let level = |height| EnvironmentLevel {
                        height,
                        temperature: 290.0,
                        vapor: None,
                    };
                    c.physics.environment.profile = vec![level(100.0), level(50.0)];
                },
                "physics.environment.profile[1].height",
            ),
            (
                |c| {
                    c.physics.environment.inversion_height = Some(800.0);
                    c.physics.environment.profile = vec![EnvironmentLevel {
                        height: 0.0,
                        temperature: 290.0,
                        vapor: None,
                    }];
                },
                "physics.environment.inversion_height",
            ),
            (
                |c| {
                    c.physics.thermodynamics = Thermodynamics::Atmospheric;
                    c.domain.size = [100.0, 20_000.0, 100.0];
                },
                "physics.thermodynamics",
            ),
            (
                |c| {
                    let level = |height| ForcingLevel {
                        height,
                        radiation: -2.0,
                        moisture: 0.0,
                        subsidence: 0.0,
                    };
                    c.physics.forcing = Some(ForcingConfig {
                        profile: vec![level(500.0), level(500.0)],
                        ..Default::default()
                    });
                },
                "physics.forcing.profile[1].height",
            ),
            (
                |c| {
                    c.physics.forcing = Some(ForcingConfig {
                        surface_layer: Some(1.0e4),
                        ..Default::default()
                    })
                },
                "physics.forcing.surface_layer",
            ),
            (
                |c| {
                    c.physics.forcing = Some(ForcingConfig {
                        surface_heat_flux: 2.0,
                        ..Default::default()
                    })
                },
                "physics.forcing.surface_heat_flux",
            ),
            (
                |c| {
                    c.output.frame_seconds = 400.0;
                    c.output.substeps = 20;
                    c.physics.forcing = Some(ForcingConfig::default());
                },
                "output.frame_seconds",
            ),
            (
                |c| {
                    c.physics.bowen_ratio = Some(0.5);
                    c.physics.latent_heat = 0.0
                },
                "physics.bowen_ratio",
            ),
            (
                |c| c.adaptive.merge_threshold = 0.5,
                "adaptive.merge_threshold",
            ),
            (
                |c| c.adaptive.capacity_factor = 0.5,
                "adaptive.capacity_factor",
            ),
            (|c| c.output.frames.end = 100_000, "output.frame_padding"),
            (|c| c.gpu.adapter = " ".into(), "gpu.adapter"),
            (|c| c.shot = "a/b".into(), "shot"),
            (|c| c.solver.iterations = 0, "solver.iterations"),
            (|c| c.solver.min_iterations = 5, "solver.min_iterations"),
            (|c| c.solver.min_iterations = 0, "solver.min_iterations"),
            (|c| c.physics.phase_rate = 10.0, "physics.phase_rate"),
            (|c| c.physics.saturation_c = -400.0, "physics.saturation_c"),
            (
                |c| c.physics.environment.lapse_rate = 10.0,
                "physics.environment.lapse_rate",
            ),
            (|c| c.physics.initial_speed = 100.0, "physics.initial_speed"),
            (
                |c| c.physics.virtual_temperature = true,
                "physics.virtual_temperature",
            ),
            (
                |c| {
                    c.physics.environment.perturbation = Some(crate::config::Perturbation {
                        temperature: 0.1,
                        vapor: 0.5,
                        height: 1600.0,
                    })
                },
                "physics.environment.perturbation.vapor",
            ),
            (
                |c| c.output.preview.sun_direction = [0.0; 3],
                "output.preview.sun_direction",
            ),
            (
                |c| {
                    c.export
                        .grids
                        .aliases
                        .insert("heat".into(), "temp".into())
                        .map_or((), drop)
                },
                "export.grids.aliases.heat",
            ),
            (
                |c| c.export.grids.vapor = "density".into(),
                "export.grids.vapor",
            ),
            (|c| c.checkpoint.keep = 0, "checkpoint.keep"),
            (
                |c| {
                    c.adaptive.enabled = true;
                    c.adaptive.split_threshold = 2.0;
                },
                "adaptive.split_threshold",
            ),
        ];
        for (edit, key) in cases {
            let mut c = base();
            edit(&mut c);
            assert_eq!(first_key(&c).as_deref(), Some(key), "{c:?}");
        }
    }

    #[test]
    fn lattice_count_is_what_the_simulation_seeds() {
        let d = base().domain;
        assert_eq!(lattice_count(&d), 20.0 * 10.0 * 20.0);
        for size in [[100.0, 53.0, 100.0], [107.0, 48.0, 102.6], [3.0, 2.0, 4.0]] {
            let mut c = base();
            c.domain.size = size;
            let (n, _) = c.domain.lattice();
            assert_eq!(
                lattice_count(&c.domain),
                (n[0] * n[1] * n[2]) as f64,
                "{size:?}"
            );
        }
    }

    #[test]
    fn max_level_matches_the_pbf_level_table() {
        let shot = crate::shot::Shot::prepare(base()).expect("the base shot");
        let p = crate::sim::pbf::PbfParams::for_shot(&shot);
        assert_eq!(p.levels.len() as u32, MAX_LEVEL + 1);
    }

    #[test]
    fn every_number_key_has_a_range() {
        let mut c = base();
        c.output.preview.camera = Some(CameraConfig {
            position: [1.0, 2.0, 3.0],
            look_at: [0.0; 3],
            fov_deg: 40.0,
        });
        // serialised only when set
        c.export.nanovdb.enabled = true;
        // Every f64 of the serialised config (JSON keeps 4.0 apart from 4) is range-checked.
        fn floats(v: &serde_json::Value, path: &str, out: &mut Vec<String>) {
            match v {
                serde_json::Value::Object(m) => {
                    for (k, x) in m {
                        let p = if path.is_empty() {
                            k.clone()
                        } else {
                            format!("{path}.{k}")
                        };
                        floats(x, &p, out);
                    }
                }
                serde_json::Value::Array(a) => {
                    for (i, x) in a.iter().enumerate() {
                        floats(x, &format!("{path}[{i}]"), out);
                    }
                }
                serde_json::Value::Number(n) if n.is_f64() => out.push(path.to_string()),
                _ => {}
            }
        }
        // every optional number of a source and the wind, too
        c.physics.sources = vec![
            HeatSource {
                shape: SourceShape::Ellipse,
                radius: None,
                radii: Some([30.0, 20.0]),
                angle: Some(10.0),
                height: Some(20.0),
                vapor: Some(1e-6),
                end: Some(100.0),
                ..HeatSource::disc(50.0, 50.0, 1.0, 0.1)
            },
            HeatSource {
                shape: SourceShape::Box,
                center: vec![50.0, 20.0, 50.0],
                radius: None,
                size: Some(vec![10.0, 10.0, 10.0]),
                ..HeatSource::disc(0.0, 0.0, 1.0, 0.1)
            },
        ];
        c.physics.wind = Some(WindConfig {
            // the default: a geostrophic wind does not relax
            time_constant: 60.0,
            profile: vec![WindLevel {
                height: 10.0,
                speed: 2.0,
                direction: 45.0,
            }],
            coriolis: Some(1.0e-4),
            surface_friction: 0.3,
            surface_layer: Some(50.0),
            ground_velocity: [1.0, -1.0],
            initial: vec![WindLevel {
                height: 20.0,
                speed: 1.0,
                direction: 10.0,
            }],
        });
        // keys left out of the JSON at their defaults (the manifest's config of earlier shots
        // stays the same) are set here, so that they are in it
        c.output.preroll = 8.0;
        c.export.optics.effective_radius = 12.0;
        c.export.optics.air_density = 1.0;
        c.physics.entrainment = 1.0e-3;
        assert_eq!(issues(&c), vec![]);
        let mut want = Vec::new();
        floats(&serde_json::to_value(&c).unwrap(), "", &mut want);
        let mut have: Vec<String> = float_values(&c).into_iter().map(|(k, _, _)| k).collect();
        want.sort();
        have.sort();
        assert_eq!(want, have);
        for (_, key, _) in float_values(&c) {
            assert!(FLOAT_RANGES.iter().any(|r| r.key == key), "{key}");
        }
    }

    #[test]
    fn digits_counts() {
        assert_eq!(digits(0), 1);
        assert_eq!(digits(9), 1);
        assert_eq!(digits(10), 2);
        assert_eq!(digits(9999), 4);
        assert_eq!(digits(u32::MAX), 10);
    }
}
