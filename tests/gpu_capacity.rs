//! The largest shot an adapter holds, known before the run (docs/ARCHITECTURE.md "Across
//! adapters"): the footprint `validate --gpu` and `run` check is what a simulation allocates,
//! and on lavapipe with its limits lowered on purpose (`NIMBUS_GPU_LIMITS`) a shot one byte or
//! one workgroup over is refused, exit 4, naming the limit and the largest count that fits,
//! with nothing written, while the shot at the limit runs.
mod common;
mod harness;

use common::{nimbus, text};
use nimbus::config::ShotConfig;
use nimbus::gpu::limits::DeviceLimits;
use nimbus::gpu::Context;
use nimbus::sim::footprint::{
    largest_count, smallest_workgroup, Footprint, ShotSize, FIXED_BYTES, READBACK_PER_PARTICLE,
};
use nimbus::sim::Simulation;
use std::sync::Arc;

/// The prepared shot of a config built here (`nimbus::shot::Shot::prepare`).
fn prepared(cfg: &nimbus::config::ShotConfig) -> nimbus::shot::Shot {
    nimbus::shot::Shot::prepare(cfg.clone()).expect("a valid shot")
}

fn context() -> Arc<Context> {
    harness::context()
}

fn tiny() -> ShotConfig {
    nimbus::shot::load(&common::sample("tiny.yaml"), &[])
        .unwrap()
        .into_config()
}

/// The footprint's device bytes (less the read-back) bound what the simulation allocates: the
/// parts that grow with the shot exactly, the fixed ones within `FIXED_BYTES`.
#[test]
fn the_footprint_bounds_what_a_simulation_allocates() {
    let ctx = context();
    let wg = smallest_workgroup(&ctx.prelude);
    for (adaptive, spacing) in [(true, 50.0), (false, 50.0), (true, 25.0), (false, 100.0)] {
        let mut cfg = tiny();
        cfg.adaptive.enabled = adaptive;
        cfg.domain.spacing = spacing;
        let n = nimbus::config::lattice_count(&cfg.domain) as u64;
        let fp = Footprint::of(&ShotSize::of(&prepared(&cfg), n), wg);
        let sim = Simulation::new(ctx.clone(), &prepared(&cfg)).unwrap();
        let actual = sim.device_bytes();
        let model = fp.device_bytes - READBACK_PER_PARTICLE * fp.capacity;
        eprintln!("adaptive {adaptive}, {n} particles: model {model} B, allocated {actual} B");
        assert_eq!(fp.capacity, sim.capacity() as u64);
        assert!(model >= actual, "{model} < {actual}");
        assert!(model <= actual + FIXED_BYTES, "{model} vs {actual}");
    }
}

/// The tiny shot's footprint on this device, and the largest count of it under `limits`.
fn tiny_footprint(ctx: &Context) -> (ShotSize, Footprint) {
    let cfg = tiny();
    let n = nimbus::config::lattice_count(&cfg.domain) as u64;
    let shot = ShotSize::of(&prepared(&cfg), n);
    let fp = Footprint::of(&shot, smallest_workgroup(&ctx.prelude));
    (shot, fp)
}

/// `validate --gpu` and `run` of samples/tiny.yaml under `limits` (NIMBUS_GPU_LIMITS): both
/// exit 4 with the same line naming `limit` and the largest count that fits, and the run
/// writes nothing; plain `validate` still accepts the config.
fn assert_refused(limits: &str, limit: &str, largest: u64) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let cfg = common::sample("tiny.yaml");
    let v = nimbus()
        .args(["validate", "--gpu"])
        .arg(&cfg)
        .env(nimbus::gpu::limits::CAP_ENV, limits)
        .output()
        .unwrap();
    assert_eq!(v.status.code(), Some(4), "{}", text(&v));
    let line = String::from_utf8_lossy(&v.stderr)
        .lines()
        .find(|l| l.contains("do not fit"))
        .unwrap_or_else(|| panic!("{}", text(&v)))
        .to_string();
    assert!(line.contains(limit), "{line}");
    let fits = match largest {
        0 => "no particle count of this shot fits".to_string(),
        n => format!("at most {n} particles of this shot fit"),
    };
    assert!(line.contains(&fits), "{line}");
    let r = nimbus()
        .arg("run")
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .env(nimbus::gpu::limits::CAP_ENV, limits)
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(4), "{}", text(&r));
    let err = String::from_utf8_lossy(&r.stderr);
    let msg = line.split_once(": ").unwrap().1;
    assert!(
        err.contains(msg),
        "run and validate --gpu differ:\n{err}\n{line}"
    );
    assert!(!out.exists(), "a refused run wrote {}", out.display());
    let plain = nimbus()
        .arg("validate")
        .arg(&cfg)
        .env(nimbus::gpu::limits::CAP_ENV, limits)
        .output()
        .unwrap();
    assert_eq!(plain.status.code(), Some(0), "{}", text(&plain));
}

/// One frame of samples/tiny.yaml under `limits` runs to the end.
fn assert_runs(limits: &str) {
    let dir = tempfile::tempdir().unwrap();
    let r = nimbus()
        .arg("run")
        .arg(common::sample("tiny.yaml"))
        .arg("--out")
        .arg(dir.path().join("run"))
        .args([
            "--set",
            "output.frames.end=1",
            "--set",
            "output.preview.enabled=false",
        ])
        .env(nimbus::gpu::limits::CAP_ENV, limits)
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(0), "{limits}: {}", text(&r));
}

fn capped(ctx: &Context, f: impl FnOnce(&mut DeviceLimits)) -> DeviceLimits {
    let mut l = ctx.limits;
    f(&mut l);
    l
}

/// A storage binding cap one 4-byte word under the tiny shot's largest array refuses it; the
/// cap equal to it runs the shot (so the estimate is the largest binding the run makes: wgpu
/// would refuse a larger one on the lowered device).
#[test]
fn the_binding_limit_is_met_exactly() {
    let ctx = context();
    let (shot, fp) = tiny_footprint(&ctx);
    let wg = smallest_workgroup(&ctx.prelude);
    let cap = fp.largest_binding - 4;
    let lim = capped(&ctx, |l| l.max_storage_buffer_binding_size = cap);
    let largest = largest_count(&shot, wg, &lim);
    assert!(largest > 0 && largest < shot.particles, "{largest}");
    assert_refused(
        &format!("max_storage_buffer_binding_size={cap}"),
        &format!("max_storage_buffer_binding_size of {cap} bytes"),
        largest,
    );
    assert_runs(&format!(
        "max_storage_buffer_binding_size={}",
        fp.largest_binding
    ));
}

/// Dispatches fold into x * y rows: a workgroup cap whose square is under the shot's largest
/// dispatch refuses it, the smallest one whose square holds it runs the shot.
#[test]
fn the_workgroup_limit_is_met_exactly() {
    let ctx = context();
    let (shot, fp) = tiny_footprint(&ctx);
    let wg = smallest_workgroup(&ctx.prelude);
    let fits = (fp.max_groups as f64).sqrt().ceil() as u32;
    assert!(fits as u64 * fits as u64 >= fp.max_groups);
    let over = fits - 1;
    let lim = capped(&ctx, |l| l.max_compute_workgroups_per_dimension = over);
    let largest = largest_count(&shot, wg, &lim);
    assert_refused(
        &format!("max_compute_workgroups_per_dimension={over}"),
        &format!("max_compute_workgroups_per_dimension of {over}"),
        largest,
    );
    assert_runs(&format!("max_compute_workgroups_per_dimension={fits}"));
}

/// Device memory is a limit where the backend reports it (Vulkan's heaps).
#[test]
fn device_memory_is_a_limit() {
    let ctx = context();
    let (shot, fp) = tiny_footprint(&ctx);
    let memory = fp.device_bytes; // 90% of it is less than the shot needs
    let lim = capped(&ctx, |l| l.device_memory = Some(memory));
    let largest = largest_count(&shot, smallest_workgroup(&ctx.prelude), &lim);
    assert_refused(
        &format!("device_memory={memory}"),
        &format!("largest memory heap ({memory} bytes)"),
        largest,
    );
}

/// `bench pbf` refuses a scene over the device's limits before it computes anything.
#[test]
fn bench_pbf_refuses_before_computing() {
    let o = nimbus()
        .args(["bench", "pbf", "--particles", "30000", "--steps", "1"])
        .env(
            nimbus::gpu::limits::CAP_ENV,
            "max_storage_buffer_binding_size=256KiB",
        )
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(4), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("max_storage_buffer_binding_size of 262144 bytes"),
        "{err}"
    );
    // 256 KiB / 16 bytes
    assert!(
        err.contains("at most 16384 particles of this shot fit"),
        "{err}"
    );
    assert!(o.stdout.is_empty(), "{}", text(&o));
}
