//! Art direction (issue 18): the wind on the whole simulation (GPU, lavapipe in CI) and bad
//! source and wind input through the real binary.
//!
//! - Momentum: with one substep per frame, what a frame adds to the horizontal momentum is the
//!   nudging term alone, f sum m (U(y) - u) (docs/PHYSICS.md "Wind"): the PBF move conserves
//!   it, so P_after = (1 - f) P_before + f sum m U(y_after) must hold frame by frame. Measured
//!   residual: printed by the test (see docs/PHYSICS.md).
//! - Periodic faces: a tagged parcel carried by a uniform wind leaves through +x, comes back
//!   through -x and keeps its fields.
//! - Bad input: exit 2, one line `FILE:LINE:COL: KEY: ...`, and a refused `run` writes nothing.
mod common;
use common::*;
use nimbus::config::{GpuConfig, ShotConfig};
use nimbus::gpu::Context;
use nimbus::ground::{ParticleState, SimClock};
use nimbus::sim::reference::thermo::wind_at;
use nimbus::sim::thermo::ThermoParams;
use nimbus::sim::Simulation;
use std::path::Path;
use std::sync::Arc;

/// The prepared shot of a config built here (`nimbus::shot::Shot::prepare`).
fn prepared(cfg: &nimbus::config::ShotConfig) -> nimbus::shot::Shot {
    nimbus::shot::Shot::prepare(cfg.clone()).expect("a valid shot")
}

fn ctx() -> Arc<Context> {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        std::env::set_var("XDG_RUNTIME_DIR", "/tmp/xdg");
    }
    Arc::new(Context::new(&GpuConfig::default()).expect("a GPU adapter (lavapipe in CI)"))
}

fn shot(yaml: &str) -> ShotConfig {
    nimbus::shot::load_str(yaml, "test.yaml", &[])
        .unwrap()
        .into_config()
}

/// Horizontal momentum (x, z) in units of m0 (every particle on level 0 here).
fn momentum(s: &ParticleState) -> [f64; 2] {
    let mut p = [0.0; 2];
    for v in &s.vel {
        p[0] += v[0] as f64;
        p[1] += v[2] as f64;
    }
    p
}

/// A sheared, turning wind over air at rest in the environment (no heating, no buoyancy): the
/// horizontal momentum changes by the nudging term and nothing else, frame by frame; the mass
/// (particle count and ids) is unchanged; and over 60 s the air takes up the wind's momentum.
#[test]
fn wind_changes_momentum_only_by_its_nudging_term() {
    let cfg = shot(
        "shot: wind\noutput: {frames: {start: 1, end: 30}, frame_seconds: 2.0, substeps: 1, max_substeps: 1}\n\
         domain: {size: [400, 300, 400], spacing: 25}\n\
         physics:\n  heat_noise: off\n  buoyancy: 0\n  cloud_weight: 0\n  initial_vapor: 0.5\n  initial_speed: 0.5\n\
         \x20 wind: {time_constant: 20, profile: [{height: 50, speed: 2, direction: 0}, {height: 250, speed: 8, direction: 60}]}\n",
    );
    let mut sim = Simulation::new(ctx(), &prepared(&cfg)).unwrap();
    let s0 = sim.state().unwrap();
    let n = s0.len();
    let mut ids0: Vec<u32> = s0.info.iter().map(|i| i[0]).collect();
    ids0.sort_unstable();
    let mut before = momentum(&s0);
    let (mut worst, mut nudge_total) = (0.0f64, [0.0f64; 2]);
    for frame in 0..30 {
        let time = sim.clock().time;
        sim.step_frame().unwrap();
        let s = sim.state().unwrap();
        let p = ThermoParams::new(&cfg, 2.0, time);
        let f = p.wind_fraction as f64;
        let mut target = [0.0; 2];
        for q in &s.pos {
            let u = wind_at(&p, q[1] as f64);
            target[0] += u[0];
            target[1] += u[1];
        }
        let after = momentum(&s);
        for a in 0..2 {
            let nudge = f * (target[a] - before[a]);
            let predicted = before[a] + nudge;
            // relative to the wind's whole momentum, sum m |U|
            let residual = (after[a] - predicted).abs() / (n as f64 * 5.0);
            worst = worst.max(residual);
            nudge_total[a] += nudge;
            assert!(
                residual < 1e-3,
                "frame {frame} axis {a}: {after:?} vs predicted {predicted} (nudge {nudge})"
            );
        }
        before = after;
        assert_eq!(s.len(), n);
        if frame == 29 {
            let mut ids: Vec<u32> = s.info.iter().map(|i| i[0]).collect();
            ids.sort_unstable();
            assert_eq!(ids, ids0, "particles appeared or vanished");
        }
    }
    // the air took up most of the wind's momentum: sum U over the particles ~ n * 5 m/s
    let taken = (nudge_total[0].powi(2) + nudge_total[1].powi(2)).sqrt() / n as f64;
    eprintln!(
        "worst frame residual {worst:.2e} of sum m |U|; nudging added {taken:.2} m/s per particle"
    );
    assert!(taken > 2.0, "the wind did not move the air: {taken} m/s");
}

/// A parcel carried by a uniform 10 m/s wind along +x through periodic faces: it leaves through
/// +x, comes back through -x (twice in 60 s over 300 m), moves the distance the wind carries
/// it, and keeps its fields (its own vapor, no cloud, its temperature, height and z).
#[test]
fn a_parcel_in_uniform_wind_crosses_the_periodic_faces_intact() {
    let cfg = shot(
        "shot: transit\noutput: {frames: {start: 1, end: 30}, frame_seconds: 2.0, substeps: 1}\n\
         domain: {size: [300, 200, 300], spacing: 25}\n\
         physics:\n  heat_noise: off\n  buoyancy: 0\n  cloud_weight: 0\n  initial_vapor: 0.6\n  initial_speed: 0\n\
         \x20 smoothing: {enabled: false}\n\
         \x20 wind: {time_constant: 1, profile: [{height: 0, speed: 10, direction: 0}]}\n",
    );
    let mut state = nimbus::sim::init::initial_particles(&cfg);
    let dist = |p: &[f32; 4]| {
        let d = [p[0] - 285.0, p[1] - 100.0, p[2] - 150.0];
        d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    };
    let k = (0..state.len())
        .min_by(|&a, &b| dist(&state.pos[a]).total_cmp(&dist(&state.pos[b])))
        .unwrap();
    let id = state.info[k][0];
    // the tag: half its neighbours' vapor
    state.thermo[k][1] *= 0.5;
    let tag = state.thermo[k];
    let start = state.pos[k];
    let size = cfg.domain.size[0] as f32;
    let mut sim =
        Simulation::from_state(ctx(), &prepared(&cfg), &state, SimClock::default()).unwrap();
    let (mut x, mut travelled, mut exits) = (start[0], 0.0f64, 0);
    for frame in 0..30 {
        sim.step_frame().unwrap();
        let s = sim.state().unwrap();
        let i = s
            .info
            .iter()
            .position(|f| f[0] == id)
            .expect("the parcel is still there");
        let (p, th) = (s.pos[i], s.thermo[i]);
        let step = p[0] - x;
        // minimum image: a jump of about -size is a pass through the +x face
        let moved = step - size * (step / size).round();
        if step < -0.5 * size {
            assert!(
                x > size - 30.0 && p[0] < 30.0,
                "frame {frame}: wrapped from {x} to {}",
                p[0]
            );
            exits += 1;
        }
        assert!(
            moved > -1.0,
            "frame {frame}: moved {moved} m against the wind"
        );
        travelled += moved as f64;
        x = p[0];
        assert_eq!(th[1], tag[1], "frame {frame}: vapor changed");
        assert_eq!(th[2], 0.0, "frame {frame}: cloud appeared");
        assert!(
            (th[0] - tag[0]).abs() < 0.05,
            "frame {frame}: T {} vs {}",
            th[0],
            tag[0]
        );
        assert!((p[1] - start[1]).abs() < 25.0, "frame {frame}: y {}", p[1]);
        assert!((p[2] - start[2]).abs() < 25.0, "frame {frame}: z {}", p[2]);
    }
    // 60 s at 10 m/s, less the first seconds of spin-up (tau = 1 s)
    eprintln!("travelled {travelled:.1} m, {exits} passes through the +x face");
    assert!(
        (560.0..=600.0).contains(&travelled),
        "travelled {travelled} m"
    );
    assert_eq!(exits, 2);
}

// ---- bad input through the binary ----

const BASE: &str = "shot: art\noutput:\n  frames: {start: 1, end: 2}\ndomain:\n  size: [800, 800, 800]\n  spacing: 50\nexport:\n  voxel_size: 25\n";

/// Writes `body` after BASE as art.yaml in `dir`.
fn config(dir: &Path, body: &str) -> std::path::PathBuf {
    let p = dir.join("art.yaml");
    std::fs::write(&p, format!("{BASE}{body}")).unwrap();
    p
}

/// validate and run exit 2 with one line naming FILE:LINE:COL and `key`, where LINE is the
/// body's line `line` (1-based, after BASE) and COL the first `token` on it; the run writes
/// nothing.
fn refused(dir: &Path, case: &Case) {
    let (body, line, token, key, words, sets) = *case;
    let cfg = config(dir, body);
    let text_line = body.lines().nth(line - 1).unwrap();
    let col = text_line.find(token).unwrap() + 1;
    let at = format!("{}:{col}", line + BASE.lines().count());
    assert_refused(&cfg, sets, &at, key, words, &dir.join("run"));
}

/// (config body, line of the body, token whose column is reported, key, words of the
/// message, --set overrides)
type Case = (
    &'static str,
    usize,
    &'static str,
    &'static str,
    &'static str,
    &'static [&'static str],
);

#[test]
fn bad_sources_and_wind_are_refused_with_their_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let grey = image::GrayImage::from_pixel(16, 16, image::Luma([128]));
    grey.save(d.join("grey.png")).unwrap();
    image::GrayImage::from_pixel(32, 16, image::Luma([128]))
        .save(d.join("wide.png"))
        .unwrap();
    image::RgbImage::from_pixel(16, 16, image::Rgb([255, 0, 0]))
        .save(d.join("red.png"))
        .unwrap();
    std::fs::write(d.join("notes.png"), "a text file").unwrap();
    let cases: Vec<Case> = vec![
        (
            "physics:\n  sources:\n    - {shape: disc, center: [900, 400], radius: 100, strength: 0.1}\n",
            3,
            "center",
            "physics.sources[0].center",
            "outside the domain along x [0, 800]",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: sphere, center: [400, 950, 400], radius: 100, strength: 0.1}\n",
            3,
            "center",
            "physics.sources[0].center",
            "outside the domain along y",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: disc, center: [400, 400], radii: [100, 50], strength: 0.1}\n",
            3,
            "radii",
            "physics.sources[0].radii",
            "does not take radii",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: sphere, center: [400, 400, 400], strength: 0.1}\n",
            3,
            "shape",
            "physics.sources[0].shape",
            "needs radius",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: box, center: [400, 400], size: [100, 100, 100], strength: 0.1}\n",
            3,
            "size",
            "physics.sources[0].size",
            "takes 2 edge lengths",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: box, center: [400, 300, 400], size: [100, 100, 100], height: 50, strength: 0.1}\n",
            3,
            "height",
            "physics.sources[0].height",
            "in the air",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: image, image: missing.png, strength: 0.1}\n",
            3,
            "image:",
            "physics.sources[0].image",
            "no such file",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: image, image: notes.png, strength: 0.1}\n",
            3,
            "image:",
            "physics.sources[0].image",
            "not a PNG or OpenEXR image",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: image, image: red.png, strength: 0.1}\n",
            3,
            "image:",
            "physics.sources[0].image",
            "colour image",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: image, image: wide.png, strength: 0.1}\n",
            3,
            "image:",
            "physics.sources[0].image",
            "the ground's aspect",
            &[],
        ),
        (
            "physics:\n  sources:\n    - {shape: image, image: grey.png, center: [1, 2], strength: 0.1}\n",
            3,
            "center",
            "physics.sources[0].center",
            "no centre",
            &[],
        ),
        (
            "physics:\n  wind:\n    profile:\n      - {height: 500, speed: 3}\n      - {height: 200, speed: 5}\n",
            5,
            "height",
            "physics.wind.profile[1].height",
            "heights must increase",
            &[],
        ),
        (
            "physics:\n  wind:\n    profile: []\n",
            3,
            "profile",
            "physics.wind.profile",
            "at least one level",
            &[],
        ),
        (
            "physics:\n  wind:\n    profile: [{height: 0, speed: 3, direction: 90}]\n",
            3,
            "direction",
            "physics.wind.profile[0].direction",
            "walled",
            &["domain.periodic=[x]"],
        ),
        (
            "physics:\n  wind:\n    profile: [{height: 0, speed: 40}]\n",
            3,
            "speed",
            "physics.wind.profile[0].speed",
            "above solver.max_speed",
            &[],
        ),
        (
            "physics:\n  wind:\n    coriolis: 1.0e-4\n    time_constant: 30\n    profile: [{height: 0, speed: 3}]\n",
            4,
            "time_constant",
            "physics.wind.time_constant",
            "does not relax it",
            &[],
        ),
        (
            "physics:\n  wind:\n    coriolis: 1.0e-4\n    profile: [{height: 0, speed: 0}]\n",
            3,
            "coriolis",
            "physics.wind.coriolis",
            "needs periodic x and z",
            &["domain.periodic=[x]"],
        ),
        (
            "physics:\n  wind:\n    ground_velocity: [0, 8]\n    profile: [{height: 0, speed: 0}]\n",
            3,
            "ground_velocity",
            "physics.wind.ground_velocity",
            "walled",
            &["domain.periodic=[x]"],
        ),
        (
            "physics:\n  heat_noise: maybe\n",
            2,
            "maybe",
            "physics.heat_noise",
            "on / off",
            &[],
        ),
    ];
    for case in &cases {
        refused(d, case);
    }
}

/// Every shape in one config validates, `heat_noise: off` is read as false, relative image
/// paths are taken from the config's directory, and the resolved config pins the image.
#[test]
fn every_shape_validates_and_images_resolve_next_to_the_config() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    image::GrayImage::from_pixel(16, 16, image::Luma([200]))
        .save(d.join("heat.png"))
        .unwrap();
    let body = "physics:\n  heat_noise: off\n  sources:\n\
        \x20   - {shape: disc, center: [400, 400], radius: 100, strength: 0.1}\n\
        \x20   - {shape: ellipse, center: [100, 700], radii: [200, 80], angle: 30, strength: 0.1, height: 150}\n\
        \x20   - {shape: box, center: [600, 200], size: [100, 300], angle: -20, strength: 0.1}\n\
        \x20   - {shape: sphere, center: [400, 500, 400], radius: 120, vapor: 1.0e-6}\n\
        \x20   - {shape: box, center: [400, 300, 400], size: [200, 50, 200], strength: 0.05}\n\
        \x20   - {shape: image, image: heat.png, strength: 0.1}\n\
        \x20 wind: {profile: [{height: 0, speed: 1}, {height: 600, speed: 6, direction: 45}]}\n";
    let path = config(d, body);
    // from another working directory: the image is found next to the config
    let o = nimbus().arg("validate").arg(&path).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let cfg = nimbus::shot::load(&path, &[]).unwrap().into_config();
    assert!(!cfg.physics.heat_noise);
    let img = &cfg.physics.sources[5];
    assert_eq!(
        Path::new(img.image.as_deref().unwrap()),
        std::path::absolute(d.join("heat.png")).unwrap()
    );
    let sha = nimbus::io::heat_map::file_sha256(&d.join("heat.png")).unwrap();
    assert_eq!(img.image_sha256.as_deref(), Some(sha.as_str()));
    // The resolved config (what the manifest holds) refuses a changed image.
    let resolved = serde_json::to_string(&cfg).unwrap();
    assert!(nimbus::shot::load_str(&resolved, "manifest.json", &[]).is_ok());
    image::GrayImage::from_pixel(16, 16, image::Luma([10]))
        .save(d.join("heat.png"))
        .unwrap();
    let e = nimbus::shot::load_str(&resolved, "manifest.json", &[])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("physics.sources[5].image_sha256") && e.contains("has changed"),
        "{e}"
    );
}

/// A run lists every source in its manifest (shape, placement, bounds, rates, schedule, the heat
/// map's absolute path and SHA-256), and the sources heat: with the noise off, the frame's
/// heating and the vapor sources' water show in stats.jsonl.
#[test]
fn a_run_lists_its_sources_in_the_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    image::GrayImage::from_fn(16, 16, |x, _| image::Luma([(x * 16) as u8]))
        .save(d.join("heat.png"))
        .unwrap();
    let body = "physics:\n  heat_noise: off\n  sources:\n\
        \x20   - {shape: disc, center: [400, 400], radius: 200, strength: 0.1, end: 600, ramp: 20}\n\
        \x20   - {shape: sphere, center: [200, 300, 600], radius: 120, vapor: 1.0e-5}\n\
        \x20   - {shape: image, image: heat.png, strength: 0.05, height: 150}\n";
    let path = config(d, body);
    let out = d.join("run");
    let o = nimbus()
        .arg("run")
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let m = manifest(&out);
    let s = m["sources"].as_array().expect("manifest.sources");
    assert_eq!(s.len(), 3, "{s:?}");
    assert_eq!(s[0]["shape"], "disc");
    assert_eq!(s[0]["placement"], "ground");
    assert_eq!(s[0]["bounds_min"], serde_json::json!([200.0, 0.0, 200.0]));
    assert_eq!(s[0]["bounds_max"], serde_json::json!([600.0, 100.0, 600.0]));
    assert_eq!(s[0]["end"], 600.0);
    assert_eq!(s[1]["placement"], "air");
    assert_eq!(s[1]["bounds_max"], serde_json::json!([320.0, 420.0, 720.0]));
    assert_eq!(s[1]["vapor"], 1.0e-5);
    assert_eq!(s[2]["bounds_max"], serde_json::json!([800.0, 150.0, 800.0]));
    let sha = nimbus::io::heat_map::file_sha256(&d.join("heat.png")).unwrap();
    assert_eq!(s[2]["image_sha256"], sha.as_str());
    assert!(Path::new(s[2]["image"].as_str().unwrap()).is_absolute());
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    let rows: Vec<serde_json::Value> = stats
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let d = |k: usize, key: &str| rows[k]["diagnostics"][key].as_f64().unwrap();
    assert!(d(1, "heat_input_mean") > 0.0);
    // the vapor source's water: the estimate (frame-end positions) against the rise of the total
    let (rise, input) = (
        d(1, "total_water") - d(0, "total_water"),
        d(1, "water_input"),
    );
    eprintln!("frame 2: total water +{rise:.1} kg, water_input {input:.1} kg");
    assert!(
        input > 0.0 && (rise - input).abs() < 0.1 * input,
        "{rise} vs {input}"
    );
}
