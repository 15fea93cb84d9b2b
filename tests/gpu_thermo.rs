//! GPU stages of the cloud physics against their f64 mirrors, on fresh random inputs.
//!
//! Tolerances: one `thermo_step` agrees with the mirror to 2e-3 K in T (f32 ulp at 300 K is
//! 3e-5 K, a handful of operations, and the GPU `exp` may be off by a few ulp), 1e-5 m/s in
//! u_y, 1e-8 kg/kg in v and w. One `smooth_temperature` iteration agrees to 2e-3 K (f32 sums
//! over ~30 neighbours of coefficients around 1e-2 K per K).
mod harness;

use nimbus::config::ShotConfig;
use nimbus::gpu::Context;
use nimbus::ground::ParticleState;
use nimbus::sim::control::Target;
use nimbus::sim::grid_params::GridParams;
use nimbus::sim::reference::grid::build_cell_table;
use nimbus::sim::reference::smoothing::{
    mix_vapor, smooth_temperature, temperature_laplacian, SmoothInput,
};
use nimbus::sim::reference::thermo::thermo_step;
use nimbus::sim::smoothing::{SmoothParams, SmoothingStage};
use nimbus::sim::thermo::{initial_thermo, LayerBuoyancy, ThermoParams, ThermoStage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The prepared shot of a config built here (`nimbus::shot::Shot::prepare`).
fn prepared(cfg: &nimbus::config::ShotConfig) -> nimbus::shot::Shot {
    nimbus::shot::Shot::prepare(cfg.clone()).expect("a valid shot")
}

fn context() -> std::sync::Arc<Context> {
    harness::context()
}

fn shot() -> ShotConfig {
    serde_saphyr::from_str(
        "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
         domain: {size: [2000.0, 3000.0, 1600.0], spacing: 40.0}\n",
    )
    .unwrap()
}

/// (pos, vel, thermo) arrays.
type State = (Vec<[f32; 4]>, Vec<[f32; 4]>, Vec<[f32; 4]>);
/// (pos, vel, thermo) borrowed.
type StateRef<'a> = (&'a [[f32; 4]], &'a [[f32; 4]], &'a [[f32; 4]]);

struct ThermoRun {
    vel: Vec<[f32; 4]>,
    thermo: Vec<[f32; 4]>,
}

/// Runs one GPU thermo step per parameter set (a submit each, as substeps are) from the given
/// state, particles in the given order.
fn gpu_thermo(
    ctx: &Context,
    cfg: &ShotConfig,
    params: &[ThermoParams],
    pos: &[[f32; 4]],
    vel: &[[f32; 4]],
    thermo: &[[f32; 4]],
) -> ThermoRun {
    gpu_thermo_with(ctx, cfg, None, params, pos, vel, thermo)
}

/// [`gpu_thermo`] with a target-shape controller and its supply map.
/// The heat maps of `cfg`'s image sources, read as the prepared shot reads them.
fn heat_maps(cfg: &ShotConfig) -> nimbus::sim::sources::HeatMaps {
    let maps: Vec<_> = cfg
        .physics
        .sources
        .iter()
        .map(|s| {
            s.image
                .as_ref()
                .map(|p| nimbus::io::heat_map::read(std::path::Path::new(p)).unwrap())
        })
        .collect();
    nimbus::sim::sources::HeatMaps::new(&maps)
}

fn gpu_thermo_with(
    ctx: &Context,
    cfg: &ShotConfig,
    target: Option<(&Target, &[f32])>,
    params: &[ThermoParams],
    pos: &[[f32; 4]],
    vel: &[[f32; 4]],
    thermo: &[[f32; 4]],
) -> ThermoRun {
    let state = ParticleState {
        pos: pos.to_vec(),
        vel: vel.to_vec(),
        thermo: thermo.to_vec(),
        info: (0..pos.len() as u32).map(|i| [i, 0]).collect(),
        density: Vec::new(),
    };
    let scene = harness::Scene::as_given(GridParams::for_shot(cfg), state, pos.len());
    let b = scene.upload(ctx);
    let maps = heat_maps(cfg).with_target(target.map(|t| t.0));
    let mut stage = ThermoStage::new(ctx, cfg, &b, maps).unwrap();
    if let Some((_, supply)) = target {
        stage.set_supply(ctx, supply);
    }
    for p in params {
        harness::submit(ctx, &b, |rec, live| stage.step_with(rec, live, p));
    }
    let (out, _) = harness::read_particles(ctx, &b);
    ThermoRun {
        vel: out.vel,
        thermo: out.thermo,
    }
}

/// Runs the f64 mirror of one thermo step on the same state and checks the GPU's `out` against
/// it (T to 2e-3 K, v and w to 1e-8, u to 1e-5 m/s); returns the positions and the mirror's
/// thermo state in f64.
#[allow(clippy::needless_range_loop)] // parallel arrays indexed together
fn check_against_mirror(
    params: &ThermoParams,
    maps: &[f32],
    (pos, vel, th): StateRef,
    out: &ThermoRun,
) -> (Vec<[f64; 3]>, Vec<[f64; 4]>) {
    let pos64: Vec<[f64; 3]> = pos
        .iter()
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let mut vel64: Vec<[f64; 4]> = vel.iter().map(|v| v.map(|c| c as f64)).collect();
    let mut th64: Vec<[f64; 4]> = th.iter().map(|t| t.map(|v| v as f64)).collect();
    thermo_step(params, maps, &pos64, &mut vel64, &mut th64);
    for i in 0..pos.len() {
        let (g, m) = (out.thermo[i], th64[i]);
        assert!(
            (g[0] as f64 - m[0]).abs() < 2e-3,
            "T {i}: {} vs {}",
            g[0],
            m[0]
        );
        assert!(
            (g[1] as f64 - m[1]).abs() < 1e-8,
            "v {i}: {} vs {}",
            g[1],
            m[1]
        );
        assert!(
            (g[2] as f64 - m[2]).abs() < 1e-8,
            "w {i}: {} vs {}",
            g[2],
            m[2]
        );
        for a in 0..3 {
            assert!(
                (out.vel[i][a] as f64 - vel64[i][a]).abs() < 1e-5,
                "u[{a}] {i}: {} vs {}",
                out.vel[i][a],
                vel64[i][a]
            );
        }
    }
    (pos64, th64)
}

fn random_thermo_state(n: usize, seed: u64, cfg: &ShotConfig) -> State {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let s = cfg.domain.size;
    let mut pos = Vec::new();
    let mut vel = Vec::new();
    let mut th = Vec::new();
    for _ in 0..n {
        // A third of the particles inside the heated layer.
        let y = if rng.random_bool(0.33) {
            rng.random_range(0.0..cfg.physics.heat_height)
        } else {
            rng.random_range(0.0..s[1])
        };
        pos.push([
            rng.random_range(0.0..s[0]) as f32,
            y as f32,
            rng.random_range(0.0..s[2]) as f32,
            0.0,
        ]);
        // w: the height gained by the substep's move (eq. 7)
        vel.push([
            rng.random_range(-1.0..1.0f32),
            rng.random_range(-6.0..6.0f32),
            rng.random_range(-1.0..1.0f32),
            rng.random_range(-12.0..12.0f32),
        ]);
        let base = initial_thermo(&cfg.physics, y);
        // Temperatures around the environment, vapor from 0.2 to 2.5 times the initial value,
        // cloud in half of them: both condensation and evaporation happen.
        let cloud = if rng.random_bool(0.5) {
            rng.random_range(0.0..0.004f32)
        } else {
            0.0
        };
        th.push([
            base[0] + rng.random_range(-4.0..4.0f32),
            base[1] * rng.random_range(0.2..2.5f32),
            cloud,
            rng.random_range(0.0..1.0f32),
        ]);
    }
    (pos, vel, th)
}

/// `physics.thermodynamics: atmospheric` (eq. 10 at the pressure of the height) against the
/// mirror, over the whole 3 km box, where the saturation is up to 1.4 times the paper's.
#[test]
fn atmospheric_thermo_step_matches_mirror() {
    let ctx = context();
    let mut cfg = shot();
    cfg.physics.thermodynamics = nimbus::config::Thermodynamics::Atmospheric;
    cfg.physics.surface_pressure = Some(101_500.0);
    let n = 3000;
    let (pos, vel, th) = random_thermo_state(n, 43, &cfg);
    let params = ThermoParams::new(&cfg, 2.0, 137.0);
    assert_eq!(params.atmospheric, 1);
    let out = gpu_thermo(&ctx, &cfg, &[params], &pos, &vel, &th);
    let (_, th64) = check_against_mirror(&params, &[], (&pos, &vel, &th), &out);
    let changed = (0..n)
        .filter(|&i| (th64[i][2] - th[i][2] as f64).abs() > 1e-7)
        .count();
    assert!(changed > n / 10, "only {changed} particles changed phase");
}

/// `physics.virtual_temperature`: eq. 6 reads T (1 + 0.608 v). GPU against the mirror, and the
/// extra lift against the formula, dt k_b 0.608 T v / T0(y) (no heating, so v is the input
/// and T the input less eq. 7's cooling over the height gained, vel.w, when eq. 6 reads them).
#[test]
fn virtual_temperature_lifts_moist_air_as_the_mirror_does() {
    let ctx = context();
    let mut cfg = shot();
    cfg.physics.heat_source = 0.0;
    cfg.physics.buoyancy_reference = nimbus::config::BuoyancyReference::LayerMean;
    let n = 3000;
    let (pos, vel, th) = random_thermo_state(n, 45, &cfg);
    let dt = 2.0;
    let plain = ThermoParams::new(&cfg, dt, 137.0);
    cfg.physics.virtual_temperature = true;
    let moist = ThermoParams::new(&cfg, dt, 137.0);
    assert_eq!(plain.virtual_factor, 0.0);
    assert_eq!(moist.virtual_factor, 0.608);
    let out_plain = gpu_thermo(&ctx, &cfg, &[plain], &pos, &vel, &th);
    let out_moist = gpu_thermo(&ctx, &cfg, &[moist], &pos, &vel, &th);
    check_against_mirror(&moist, &[], (&pos, &vel, &th), &out_moist);
    let mut worst: f64 = 0.0;
    let mut lifted = 0;
    for i in 0..n {
        let t0 = nimbus::sim::thermo::environment_temperature(&cfg.physics, pos[i][1] as f64);
        let t = th[i][0] as f64 - cfg.physics.adiabatic_lapse_rate * vel[i][3] as f64;
        let want = dt * cfg.physics.buoyancy * 0.608 * t * th[i][1] as f64 / t0;
        let got = out_moist.vel[i][1] as f64 - out_plain.vel[i][1] as f64;
        worst = worst.max((got - want).abs());
        lifted += usize::from(want > 0.01);
    }
    // f32 velocities near 1 m/s: ulp 1.2e-7; a few operations.
    assert!(worst < 2e-5, "extra lift off by {worst} m/s");
    assert!(
        lifted > n / 2,
        "only {lifted} particles got 0.01 m/s of lift"
    );
}

/// `physics.environment.profile` (the BOMEX sounding's temperatures) in eq. 6 against the
/// mirror, with atmospheric thermodynamics.
#[test]
fn profile_thermo_step_matches_mirror() {
    let ctx = context();
    let mut cfg = shot();
    cfg.physics.thermodynamics = nimbus::config::Thermodynamics::Atmospheric;
    cfg.physics.environment.profile = serde_saphyr::from_str(
        "[{height: 0, temperature: 299.1}, {height: 520, temperature: 294.0}, \
         {height: 1480, temperature: 288.3}, {height: 2000, temperature: 289.0}, \
         {height: 3000, temperature: 282.9}]",
    )
    .unwrap();
    let n = 3000;
    let (pos, vel, th) = random_thermo_state(n, 44, &cfg);
    let params = ThermoParams::new(&cfg, 2.0, 137.0);
    assert_eq!(params.n_env, 5);
    let out = gpu_thermo(&ctx, &cfg, &[params], &pos, &vel, &th);
    check_against_mirror(&params, &[], (&pos, &vel, &th), &out);
}

#[test]
fn thermo_step_matches_mirror() {
    let ctx = context();
    let mut cfg = shot();
    // Every term of T0(y) and of the heating: an inversion inside the box and a disc source
    // across the periodic x face besides the noise, and a moist ground that evaporates.
    cfg.physics.bowen_ratio = Some(0.5);
    cfg.physics.environment.inversion_height = Some(1500.0);
    cfg.physics.environment.inversion_strength = 3.0;
    cfg.physics.environment.lapse_rate_above = Some(0.002);
    cfg.physics.sources.push(nimbus::config::HeatSource {
        start: 100.0,
        end: Some(300.0),
        ramp: 50.0,
        ..nimbus::config::HeatSource::disc(1900.0, 800.0, 400.0, 0.1)
    });
    let n = 3000;
    let (pos, vel, th) = random_thermo_state(n, 42, &cfg);
    // and a horizontal-mean buoyancy profile (physics.buoyancy_reference: layer_mean) of
    // different values per layer, read between the layer centres and clamped at the ends
    let layers = LayerBuoyancy {
        layer_height: cfg.domain.size[1] / 7.0,
        values: (0..7).map(|k| 0.01 * (k as f64 - 2.5).powi(2)).collect(),
    };
    let params = ThermoParams::new(&cfg, 2.0, 137.0).with_layers(&layers);
    let out = gpu_thermo(&ctx, &cfg, &[params], &pos, &vel, &th);
    let (_, th64) = check_against_mirror(&params, &[], (&pos, &vel, &th), &out);

    let (mut heated, mut condensed, mut evaporated, mut moistened) = (0, 0, 0, 0);
    for i in 0..n {
        let (g, m) = (out.thermo[i], th64[i]);
        assert_eq!(g[3], th[i][3], "shape energy is not ours to change");
        assert_eq!([out.vel[i][0], out.vel[i][2]], [vel[i][0], vel[i][2]]);
        heated += (pos[i][1] < cfg.physics.heat_height as f32) as usize;
        condensed += (m[2] > th[i][2] as f64) as usize;
        evaporated += (m[2] < th[i][2] as f64) as usize;
        moistened += (m[1] + m[2] > th[i][1] as f64 + th[i][2] as f64 + 1e-7) as usize;
    }
    assert!(
        heated > 100 && condensed > 100 && evaporated > 100 && moistened > 50,
        "{heated} {condensed} {evaporated} {moistened}"
    );
}

/// Every source shape (rotated, across periodic faces, on the ground with its own layer, in
/// the air, a heat map with alpha, vapor rates, a schedule) and a sheared, turning wind: one
/// GPU step against the mirror, with the tolerances above (u_x, u_z too). Each source must
/// heat some particles, the map must be sampled between pixels, and the wind must move u_x
/// and u_z.
#[test]
#[allow(clippy::needless_range_loop)] // parallel arrays indexed together
fn sources_and_wind_match_mirror() {
    use nimbus::config::{HeatSource, SourceShape, WindConfig, WindLevel};
    let ctx = context();
    let dir = tempfile::tempdir().unwrap();
    // 40 x 32 pixels over the 2000 x 1600 m ground: random grey with random alpha
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut im = image::RgbaImage::new(40, 32);
    for px in im.pixels_mut() {
        let v: u8 = rng.random();
        *px = image::Rgba([v, v, v, rng.random()]);
    }
    let map_path = dir.path().join("heat.png");
    im.save(&map_path).unwrap();

    let mut cfg = shot();
    cfg.physics.bowen_ratio = Some(0.5);
    let src = |shape: SourceShape, center: Vec<f64>, strength: f64| HeatSource {
        shape,
        center,
        radius: None,
        strength,
        ..HeatSource::disc(0.0, 0.0, 1.0, 0.0)
    };
    cfg.physics.sources = vec![
        HeatSource {
            radii: Some([500.0, 200.0]),
            angle: Some(35.0),
            vapor: Some(2e-5),
            ..src(SourceShape::Ellipse, vec![1900.0, 100.0], 0.2)
        },
        HeatSource {
            size: Some(vec![600.0, 300.0]),
            angle: Some(-60.0),
            height: Some(400.0),
            ..src(SourceShape::Box, vec![600.0, 1000.0], 0.3)
        },
        HeatSource {
            radius: Some(450.0),
            vapor: Some(1e-5),
            ..src(SourceShape::Sphere, vec![1000.0, 1500.0, 50.0], 0.1)
        },
        HeatSource {
            size: Some(vec![800.0, 500.0, 700.0]),
            angle: Some(20.0),
            start: 100.0,
            end: Some(300.0),
            ramp: 50.0,
            ..src(SourceShape::Box, vec![1200.0, 2200.0, 800.0], 0.15)
        },
        HeatSource {
            image: Some(map_path.to_string_lossy().into_owned()),
            height: Some(300.0),
            vapor: Some(5e-6),
            ..src(SourceShape::Image, vec![], 0.25)
        },
        HeatSource {
            vapor: Some(3e-5),
            ..HeatSource::disc(300.0, 1500.0, 300.0, 0.05)
        },
    ];
    cfg.physics.wind = Some(WindConfig {
        time_constant: 20.0,
        profile: vec![
            WindLevel {
                height: 200.0,
                speed: 2.0,
                direction: 350.0,
            },
            WindLevel {
                height: 1200.0,
                speed: 9.0,
                direction: 30.0,
            },
            WindLevel {
                height: 2500.0,
                speed: 12.0,
                direction: 120.0,
            },
        ],
        coriolis: None,
        surface_friction: 0.0,
        surface_layer: None,
        ground_velocity: [0.0; 2],
        initial: Vec::new(),
    });
    let maps = heat_maps(&cfg);
    assert_eq!(maps.values.len(), 40 * 32);
    let n = 6000;
    let (mut pos, vel, th) = random_thermo_state(n, 43, &cfg);
    // half of them inside the heated layers of the ground shapes (up to 400 m)
    for p in pos.iter_mut().step_by(2) {
        p[1] = (p[1] as f64 % 450.0) as f32;
    }
    let params = ThermoParams::new(&cfg, 2.0, 150.0).with_maps(&maps);
    let out = gpu_thermo(&ctx, &cfg, &[params], &pos, &vel, &th);

    let (pos64, _) = check_against_mirror(&params, &maps.values, (&pos, &vel, &th), &out);
    for i in 0..n {
        assert!(
            (out.vel[i][0] - vel[i][0]).abs() > 1e-3 || (out.vel[i][2] - vel[i][2]).abs() > 1e-3,
            "the wind moved nothing at {i}"
        );
    }
    // every source reaches some particles, and some only partly (the falloff is exercised)
    for (k, s) in params.sources[..params.n_sources as usize]
        .iter()
        .enumerate()
    {
        let mut one = params;
        one.sources[0] = *s;
        one.n_sources = 1;
        one.heat_noise = 0;
        let (mut full, mut part) = (0, 0);
        for q in &pos64 {
            let r = nimbus::sim::reference::thermo::source_rates(&one, &maps.values, *q)[0];
            let f = r / s.rate[2] as f64;
            assert!(f <= 1.0 + 1e-9, "source {k}: fraction {f}");
            full += (f > 0.999) as usize;
            part += (f > 0.01 && f < 0.99) as usize;
        }
        // a heat map of random grey and alpha is seldom at full strength
        let image = s.kind[0] == nimbus::sim::sources::KIND_IMAGE;
        assert!(
            (full > 10 || image) && part > 10,
            "source {k}: {full} full, {part} partly"
        );
    }
}

/// Fifty steps on the GPU: v + w per particle kept to f32 rounding, never negative, and the
/// run is bit-reproducible.
#[test]
#[allow(clippy::needless_range_loop)] // parallel arrays indexed together
fn gpu_phase_transition_conserves_water_and_is_deterministic() {
    let ctx = context();
    let mut cfg = shot();
    cfg.physics.phase_rate = 1.0;
    let n = 2000;
    let (pos, vel, th) = random_thermo_state(n, 7, &cfg);
    let params: Vec<ThermoParams> = (0..50)
        .map(|k| ThermoParams::new(&cfg, 2.0, k as f64 * 2.0))
        .collect();
    let a = gpu_thermo(&ctx, &cfg, &params, &pos, &vel, &th);
    let b = gpu_thermo(&ctx, &cfg, &params, &pos, &vel, &th);
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&a.thermo),
        bytemuck::cast_slice::<_, u8>(&b.thermo)
    );
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&a.vel),
        bytemuck::cast_slice::<_, u8>(&b.vel)
    );
    let (mut total0, mut total1) = (0.0f64, 0.0f64);
    for i in 0..n {
        let s0 = th[i][1] + th[i][2];
        let s1 = a.thermo[i][1] + a.thermo[i][2];
        // Each step may round v + w by half an ulp: 50 steps, a few ulp at most.
        assert!(
            (s1 - s0).abs() <= 50.0 * f32::EPSILON * s0,
            "{i}: {s0} -> {s1}"
        );
        assert!(a.thermo[i][1] >= 0.0 && a.thermo[i][2] >= 0.0);
        total0 += s0 as f64;
        total1 += s1 as f64;
    }
    assert!((total1 - total0).abs() < 1e-5 * total0);
}

/// Heating off, particles at rest in the sub-saturated initial state: no cloud appears.
#[test]
#[allow(clippy::needless_range_loop)] // parallel arrays indexed together
fn gpu_nothing_condenses_without_heating() {
    let ctx = context();
    let mut cfg = shot();
    cfg.physics.heat_source = 0.0;
    let n = 1000;
    let pos: Vec<[f32; 4]> = (0..n)
        .map(|k| {
            [
                (k * 37 % 2000) as f32,
                (k * 3) as f32,
                (k * 53 % 1600) as f32,
                0.0,
            ]
        })
        .collect();
    let th: Vec<[f32; 4]> = pos
        .iter()
        .map(|p| initial_thermo(&cfg.physics, p[1] as f64))
        .collect();
    let vel = vec![[0.0f32; 4]; n];
    let params: Vec<ThermoParams> = (0..100)
        .map(|k| ThermoParams::new(&cfg, 2.0, k as f64 * 2.0))
        .collect();
    let out = gpu_thermo(&ctx, &cfg, &params, &pos, &vel, &th);
    for i in 0..n {
        assert_eq!(out.thermo[i][2], 0.0, "cloud appeared at {i}");
        assert_eq!(out.thermo[i][1], th[i][1]);
        // T0(y) rounded to f32 gives a 1e-5 K excess at most: negligible buoyancy.
        assert!((out.thermo[i][0] - th[i][0]).abs() < 1e-3);
        assert!(out.vel[i][1].abs() < 1e-3);
    }
}

/// Random cell-ordered particles (mixed levels) in a periodic box with boundary layers.
struct Scene {
    grid: GridParams,
    pos: Vec<[f64; 3]>,
    level: Vec<u32>,
    temp: Vec<f64>,
    cell_start: Vec<u32>,
    boundary: Vec<[f64; 4]>,
    boundary_cell_start: Vec<u32>,
}

fn scene(seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d = 10.0; // spacing, h0 = 20
    let size = [120.0, 100.0, 80.0];
    let grid = GridParams::new(size, 2.0 * d, true, true);
    let mut pos = Vec::new();
    let mut level = Vec::new();
    let mut temp = Vec::new();
    let dims = size.map(|s| (s / d) as usize);
    for i in 0..dims[0] {
        for j in 0..dims[1] {
            for k in 0..dims[2] {
                let p = [i, j, k].map(|v| (v as f64 + 0.5) * d);
                let jit = [0, 1, 2].map(|_| rng.random_range(-0.3..0.3) * d);
                // Wrap jittered x and z into the periodic box.
                // Rounded to f32 first, so the CPU cell table matches the positions the GPU reads.
                let q = [
                    (p[0] + jit[0]).rem_euclid(size[0]),
                    p[1] + jit[1],
                    (p[2] + jit[2]).rem_euclid(size[2]),
                ];
                pos.push(q.map(|v| v as f32 as f64));
                level.push(rng.random_range(0..3u32));
                temp.push(rng.random_range(280.0..300.0));
            }
        }
    }
    let mut bpos = Vec::new();
    for i in 0..dims[0] {
        for k in 0..dims[2] {
            for (y, t) in [
                (-0.5 * d, 297.0),
                (-1.5 * d, 297.0),
                (size[1] + 0.5 * d, 283.0),
                (size[1] + 1.5 * d, 283.0),
            ] {
                bpos.push([(i as f64 + 0.5) * d, y, (k as f64 + 0.5) * d, t]);
            }
        }
    }
    let (order, cell_start) = build_cell_table(&grid, &pos);
    let b3: Vec<[f64; 3]> = bpos.iter().map(|b| [b[0], b[1], b[2]]).collect();
    let (border, boundary_cell_start) = build_cell_table(&grid, &b3);
    Scene {
        grid,
        pos: order.iter().map(|&o| pos[o as usize]).collect(),
        level: order.iter().map(|&o| level[o as usize]).collect(),
        temp: order.iter().map(|&o| temp[o as usize]).collect(),
        cell_start,
        boundary: border.iter().map(|&o| bpos[o as usize]).collect(),
        boundary_cell_start,
    }
}

fn smooth_params(kappa: f32) -> SmoothParams {
    SmoothParams {
        lapse: 0.0,
        h0: 20.0,
        kappa,
        epsilon: 1e-2,
        volume0: 1000.0,
        fixed_walls: 1,
        vapor_rate: 0.0,
        conservative: 0,
        mix_everywhere: 0,
        _pad: [0; 3],
    }
}

/// Runs `iterations` GPU smoothing iterations on the scene; returns the thermo array.
fn gpu_smooth(
    ctx: &Context,
    s: &Scene,
    p: &SmoothParams,
    iterations: u32,
    thermo: &[[f32; 4]],
) -> Vec<[f32; 4]> {
    let mut cfg = shot();
    cfg.physics.smoothing.enabled = true;
    if p.vapor_rate > 0.0 {
        // the stage keeps a limiter only for shots that mix
        cfg.physics.smoothing.vapor_diffusivity = 1.0;
    }
    let n = s.pos.len();
    let mut grid = s.grid;
    grid.n_boundary = s.boundary.len() as u32;
    let scene = harness::Scene {
        grid,
        state: ParticleState {
            pos: s
                .pos
                .iter()
                .map(|q| [q[0] as f32, q[1] as f32, q[2] as f32, 0.0])
                .collect(),
            vel: vec![[0.0; 4]; n],
            thermo: thermo.to_vec(),
            info: s
                .level
                .iter()
                .enumerate()
                .map(|(i, &l)| [i as u32, l])
                .collect(),
            density: vec![0.0; n],
        },
        cell_start: s.cell_start.clone(),
        boundary: (
            s.boundary.iter().map(|b| b.map(|v| v as f32)).collect(),
            s.boundary_cell_start.clone(),
        ),
        capacity: n.next_multiple_of(64) as u32,
        next_id: n as u32,
    };
    let b = scene.upload(ctx);
    let stage = SmoothingStage::new(ctx, &cfg, &b).unwrap();
    let (out, _) = harness::run_gpu(ctx, &b, |rec, live| {
        stage.smooth_with(rec, live, p, iterations)
    });
    out.thermo
}

fn mirror_input<'a>(
    s: &'a Scene,
    p: &'a SmoothParams,
    pos: &'a [[f64; 3]],
    t: &'a [f64],
) -> SmoothInput<'a> {
    SmoothInput {
        grid: &s.grid,
        params: p,
        pos,
        level: &s.level,
        temperature: t,
        cell_start: &s.cell_start,
        boundary: &s.boundary,
        boundary_cell_start: &s.boundary_cell_start,
    }
}

/// The GPU's smoothed T against the mirror's `t` (2e-3 K); returns the mirror's largest change
/// from `before`.
fn assert_temperatures_match(seed: u64, gpu: &[[f32; 4]], t: &[f64], before: &[f64]) -> f64 {
    let mut max_change = 0.0f64;
    for i in 0..t.len() {
        assert!(
            (gpu[i][0] as f64 - t[i]).abs() < 2e-3,
            "seed {seed} particle {i}: {} vs {}",
            gpu[i][0],
            t[i]
        );
        max_change = max_change.max((t[i] - before[i]).abs());
    }
    max_change
}

/// The conservative form (physics.smoothing.conservative) against its mirror, with fixed walls
/// and without, and the heat it keeps: without walls sum m T moves by f32 rounding only (the
/// paper's step moves it by far more on the same scene).
#[test]
fn conservative_smoothing_matches_mirror_and_keeps_the_heat() {
    let ctx = context();
    for (seed, kappa, fixed) in [(15, 0.1f32, 1u32), (16, 1.0, 0), (17, 0.3, 0)] {
        let s = scene(seed);
        let mut p = smooth_params(kappa);
        p.conservative = 1;
        p.fixed_walls = fixed;
        // the form smooths T + Gamma_d y
        p.lapse = 0.0098;
        let thermo: Vec<[f32; 4]> = s
            .temp
            .iter()
            .map(|&t| [t as f32, 0.01, 0.002, 0.5])
            .collect();
        let gpu = gpu_smooth(&ctx, &s, &p, 1, &thermo);
        let t0: Vec<f64> = thermo.iter().map(|v| v[0] as f64).collect();
        let t = nimbus::sim::reference::smoothing::smooth_temperature_conservative(&mirror_input(
            &s, &p, &s.pos, &t0,
        ));
        let max_change = assert_temperatures_match(seed, &gpu, &t, &t0);
        assert!(
            max_change > 0.5,
            "the test must smooth something: {max_change}"
        );
        if fixed == 0 {
            let mass = |i: usize| (-(s.level[i] as f64)).exp2();
            let heat =
                |t: &dyn Fn(usize) -> f64| (0..t0.len()).map(|i| mass(i) * t(i)).sum::<f64>();
            let before = heat(&|i| t0[i]);
            let kept = heat(&|i| t[i]) - before;
            let gpu_kept = heat(&|i| gpu[i][0] as f64) - before;
            p.conservative = 0;
            p.lapse = 0.0;
            let paper = smooth_temperature(&mirror_input(&s, &p, &s.pos, &t0));
            let paper_kept = heat(&|i| paper[i]) - before;
            eprintln!(
                "seed {seed}: sum m dT conservative mirror {kept:.3e}, GPU {gpu_kept:.3e}, paper {paper_kept:.3e}"
            );
            assert!(kept.abs() < 1e-9 * before.abs(), "mirror: {kept}");
            assert!(gpu_kept.abs() < 1e-6 * before.abs(), "GPU: {gpu_kept}");
            assert!(
                paper_kept.abs() > 100.0 * kept.abs().max(1e-9),
                "paper: {paper_kept}"
            );
        }
    }
}

/// The conservative form keeps the heat in f32 also where each flux is below half an ulp of T:
/// a few warm particles among air at one temperature lose about 3 ulps an iteration each, and
/// each neighbour gains about a tenth of an ulp. A plain f32 sum keeps the losses and drops
/// most gains (emulated here from the mirror's fluxes: it loses 16% of the heat moved), which
/// is how the BOMEX shot gained heat at 8 substeps (docs/PHYSICS.md "Heat budget"); the GPU
/// adds each flux with stochastic rounding (`add_unbiased`): 0.3% on lavapipe.
#[test]
fn conservative_smoothing_keeps_the_heat_of_fluxes_below_an_ulp() {
    let ctx = context();
    let s = scene(18);
    let mut p = smooth_params(1e-4);
    p.conservative = 1;
    p.fixed_walls = 0;
    let iterations = 40;
    let t0: Vec<f64> = (0..s.pos.len())
        .map(|i| if i % 40 == 0 { 291.0 } else { 290.0 })
        .collect();
    let thermo: Vec<[f32; 4]> = t0.iter().map(|&t| [t as f32, 0.01, 0.0, 0.5]).collect();
    let gpu = gpu_smooth(&ctx, &s, &p, iterations, &thermo);
    let smooth = |t: &[f64]| {
        nimbus::sim::reference::smoothing::smooth_temperature_conservative(&mirror_input(
            &s, &p, &s.pos, t,
        ))
    };
    let (mut exact, mut plain) = (t0.clone(), t0.clone());
    for _ in 0..iterations {
        exact = smooth(&exact);
        // the f32 sum T - flux of a plain shader, with the mirror's flux of the f32 state
        let next = smooth(&plain);
        plain = (0..plain.len())
            .map(|i| (plain[i] as f32 - (plain[i] - next[i]) as f32) as f64)
            .collect();
    }
    assert_temperatures_match(18, &gpu, &exact, &t0);
    let mass = |i: usize| (-(s.level[i] as f64)).exp2();
    let sum = |f: &dyn Fn(usize) -> f64| (0..t0.len()).map(|i| mass(i) * f(i)).sum::<f64>();
    let moved = sum(&|i| (exact[i] - t0[i]).abs());
    let gpu_kept = sum(&|i| gpu[i][0] as f64 - t0[i]);
    let plain_kept = sum(&|i| plain[i] - t0[i]);
    eprintln!(
        "heat moved {moved:.3e} K; sum m dT: GPU {gpu_kept:.3e}, plain f32 sum {plain_kept:.3e}"
    );
    assert!(
        plain_kept.abs() > 0.1 * moved,
        "the fluxes must be below an ulp: {plain_kept}"
    );
    assert!(gpu_kept.abs() < 0.03 * moved, "GPU: {gpu_kept} of {moved}");
}

#[test]
fn smooth_temperature_matches_mirror() {
    let ctx = context();
    for (seed, kappa, iterations) in [(5, 0.1f32, 1u32), (6, 1.0, 1), (8, 0.1, 3)] {
        let s = scene(seed);
        let p = smooth_params(kappa);
        let thermo: Vec<[f32; 4]> = s
            .temp
            .iter()
            .map(|&t| [t as f32, 0.01, 0.002, 0.5])
            .collect();
        let gpu = gpu_smooth(&ctx, &s, &p, iterations, &thermo);
        // The mirror starts from the same f32 inputs.
        let mut t: Vec<f64> = thermo.iter().map(|v| v[0] as f64).collect();
        for _ in 0..iterations {
            t = smooth_temperature(&mirror_input(&s, &p, &s.pos, &t));
        }
        let max_change = assert_temperatures_match(seed, &gpu, &t, &s.temp);
        for i in 0..s.pos.len() {
            assert_eq!(&gpu[i][1..], &thermo[i][1..], "only T changes");
        }
        assert!(
            max_change > 0.5,
            "the test must smooth something: {max_change}"
        );
    }
}

/// Vapor mixing (the .y of the same pass) against its mirror, with temperature smoothing on:
/// 3 iterations at 10 times the rate a lattice of levels 0-2 takes explicitly (the limiter
/// holds it), every third particle cloudy (only pairs with cloud mix). Measured: agrees to
/// about 1e-9 kg/kg (tolerance 1e-8; values around 1e-2), and sum m v moves by about 1e-8
/// relative in f32 (tolerance 1e-6, the total-water budget).
#[test]
fn gpu_vapor_mixing_matches_mirror_and_conserves() {
    vapor_mixing_against_mirror(0);
}

/// The same with `vapor_mixing: everywhere`: clear pairs mix too (the test fails if the
/// shader skips them: the mirror then moves the clear particles and the GPU does not).
#[test]
fn gpu_vapor_mixing_everywhere_matches_mirror_and_conserves() {
    vapor_mixing_against_mirror(1);
}

fn vapor_mixing_against_mirror(mix_everywhere: u32) {
    let ctx = context();
    let s = scene(21);
    let mut p = smooth_params(0.1);
    let h_min = p.h0 as f64 * (-2.0f64 / 3.0).exp2();
    p.vapor_rate = (10.0 * 2.0 * h_min * h_min / 40.0) as f32;
    p.mix_everywhere = mix_everywhere;
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let thermo: Vec<[f32; 4]> = s
        .temp
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let w = if i % 3 == 0 { 0.001 } else { 0.0 };
            [t as f32, rng.random_range(0.0..0.02), w, 0.5]
        })
        .collect();
    let cloud: Vec<f64> = thermo.iter().map(|v| v[2] as f64).collect();
    let iterations = 3;
    let gpu = gpu_smooth(&ctx, &s, &p, iterations, &thermo);
    let mut t: Vec<f64> = thermo.iter().map(|v| v[0] as f64).collect();
    let mut v: Vec<f64> = thermo.iter().map(|v| v[1] as f64).collect();
    for _ in 0..iterations {
        let input = mirror_input(&s, &p, &s.pos, &t);
        let next_v = mix_vapor(&input, &v, &cloud);
        t = smooth_temperature(&input);
        v = next_v;
    }
    let mass = |v: &mut dyn Iterator<Item = f64>| -> f64 {
        v.zip(&s.level)
            .map(|(v, &l)| v * (-(l as f64)).exp2())
            .sum()
    };
    let (mut worst, mut moved) = (0.0f64, 0.0f64);
    for i in 0..s.pos.len() {
        let d = (gpu[i][1] as f64 - v[i]).abs();
        worst = worst.max(d);
        moved = moved.max((v[i] - thermo[i][1] as f64).abs());
        assert!(d < 1e-8, "particle {i}: {} vs {}", gpu[i][1], v[i]);
        assert!((gpu[i][0] as f64 - t[i]).abs() < 2e-3, "T of {i}");
        assert!(gpu[i][1] >= 0.0);
    }
    let m0 = mass(&mut thermo.iter().map(|x| x[1] as f64));
    let m1 = mass(&mut gpu.iter().map(|x| x[1] as f64));
    println!("vapor (everywhere {mix_everywhere}): worst GPU-mirror {worst:.2e}, largest change {moved:.2e}, mass {m0} -> {m1} ({:.2e})", (m1 - m0) / m0);
    assert!(moved > 1e-3, "the test must mix something: {moved}");
    assert!(((m1 - m0) / m0).abs() < 1e-6);
    // with everywhere, particles with no cloudy neighbour move too
    let clear_moved = (0..s.pos.len())
        .filter(|&i| cloud[i] <= 0.0)
        .map(|i| (v[i] - thermo[i][1] as f64).abs())
        .fold(0.0f64, f64::max);
    if mix_everywhere != 0 {
        assert!(clear_moved > 1e-3, "clear air must mix: {clear_moved}");
    }
}

/// On the GPU too: sum (lap T)^2 drops every iteration, and a run is bit-reproducible.
#[test]
fn gpu_smoothing_lowers_laplacian_norm_and_is_deterministic() {
    let ctx = context();
    let s = scene(12);
    let p = smooth_params(0.1);
    let mut thermo: Vec<[f32; 4]> = s.temp.iter().map(|&t| [t as f32, 0.0, 0.0, 0.0]).collect();
    let norm = |th: &[[f32; 4]]| {
        let t: Vec<f64> = th.iter().map(|v| v[0] as f64).collect();
        temperature_laplacian(&mirror_input(&s, &p, &s.pos, &t))
            .iter()
            .map(|c| c * c)
            .sum::<f64>()
    };
    let mut prev = norm(&thermo);
    for it in 0..5 {
        let next = gpu_smooth(&ctx, &s, &p, 1, &thermo);
        let now = norm(&next);
        assert!(now < prev, "iteration {it}: {prev} -> {now}");
        prev = now;
        thermo = next;
    }
    let a = gpu_smooth(&ctx, &s, &p, 4, &thermo);
    let b = gpu_smooth(&ctx, &s, &p, 4, &thermo);
    assert_eq!(
        bytemuck::cast_slice::<_, u8>(&a),
        bytemuck::cast_slice::<_, u8>(&b)
    );
}

/// The target-shape control (supply map, footprint mask on the noise heating, pull towards the
/// target) on the GPU against the mirror, with a supply map that varies column by column.
#[test]
#[allow(clippy::needless_range_loop)] // parallel arrays indexed together
fn target_control_matches_mirror() {
    let ctx = context();
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("cube.obj");
    std::fs::write(
        &mesh,
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
         f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n",
    )
    .unwrap();
    let cfg = nimbus::shot::load_str(
        &format!(
            "shot: t\noutput: {{frames: {{start: 1, end: 2}}}}\n\
             domain: {{size: [2000.0, 3000.0, 1600.0], spacing: 40.0}}\n\
             control:\n  target: {{mesh: {}, scale: [800, 1200, 600], rotate_y: 20, translate: [700, 500, 400], \
             heat: 0.4, vapor: 2.0e-5, supply_height: 150, pull: 0.5, reach: 500, margin: 200}}\n",
            mesh.display()
        ),
        "t.yaml",
        &[],
    )
    .unwrap().into_config();
    let target = Target::of_shot(&prepared(&cfg)).unwrap();
    let supply: Vec<f32> = (0..target.grid.columns())
        .map(|c| {
            if target.top[c] > 0.0 {
                (c % 5) as f32 / 4.0
            } else {
                0.0
            }
        })
        .collect();
    let mut maps = heat_maps(&cfg).with_target(Some(&target));
    assert!(maps.set_supply(&supply).is_some());
    let n = 6000;
    let (mut pos, vel, mut th) = random_thermo_state(n, 44, &cfg);
    // a third in the supplied layer, a third around the target with cloud
    for (i, p) in pos.iter_mut().enumerate() {
        match i % 3 {
            0 => p[1] = (p[1] as f64 % 150.0) as f32,
            1 => {
                p[0] = 400.0 + (p[0] % 1400.0);
                p[1] = 300.0 + (p[1] % 1600.0);
                p[2] = 200.0 + (p[2] % 1000.0);
                th[i][2] = th[i][2].max(1.0e-4);
            }
            _ => {}
        }
    }
    let params = ThermoParams::new(&cfg, 2.0, 150.0).with_maps(&maps);
    assert_eq!(params.control[0], 1);
    let out = gpu_thermo_with(
        &ctx,
        &cfg,
        Some((&target, &supply)),
        &[params],
        &pos,
        &vel,
        &th,
    );
    let (pos64, _) = check_against_mirror(&params, &maps.values, (&pos, &vel, &th), &out);
    let (mut pulled, mut supplied) = (0, 0);
    for i in 0..n {
        let p = nimbus::sim::reference::thermo::target_pull(
            &params,
            &maps.values,
            pos64[i],
            th[i][2] as f64,
        );
        pulled += (p.iter().map(|x| x * x).sum::<f64>() > 0.0) as usize;
        let r = nimbus::sim::reference::thermo::source_rates(&params, &maps.values, pos64[i]);
        supplied += (r[1] > 0.0) as usize;
    }
    assert!(pulled > 100, "{pulled} particles pulled");
    assert!(supplied > 100, "{supplied} particles supplied with vapor");
}
