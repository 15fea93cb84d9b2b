//! What differs between adapters, on the one adapter CI has (docs/ARCHITECTURE.md "Across
//! adapters"): the device is the one the environment asks for (so each of .ci/run's passes —
//! the validation layer, OpenGL, the forced workgroup sizes — runs what it says), and
//! dispatches folded into rows, as those over 65,535 workgroups are, give the same frames as
//! unfolded ones.
mod harness;

use nimbus::config::{Backend, GpuConfig, ShotConfig};
use nimbus::gpu::Context;
use nimbus::sim::Simulation;
use std::sync::Arc;

/// The prepared shot of a config built here (`nimbus::shot::Shot::prepare`).
fn prepared(cfg: &nimbus::config::ShotConfig) -> nimbus::shot::Shot {
    nimbus::shot::Shot::prepare(cfg.clone()).expect("a valid shot")
}

/// The suites' device, owned (a test lowers its prelude's dispatch limit).
fn context() -> Context {
    Arc::into_inner(harness::context()).unwrap()
}

/// WGPU_BACKEND, NIMBUS_GPU_WORKGROUP, NIMBUS_GPU_VALIDATION and NIMBUS_GPU_LIMITS reach the
/// device the suites open (`GpuConfig::default()`, as every suite does).
#[test]
fn the_device_is_the_one_the_environment_asks_for() {
    let ctx = context();
    eprintln!(
        "adapter {} ({:?}), prelude {:?}, validation {}, limits {:?}",
        ctx.adapter_info.name, ctx.adapter_info.backend, ctx.prelude, ctx.validation, ctx.limits
    );
    match std::env::var("WGPU_BACKEND").ok().as_deref() {
        Some("gl") => assert_eq!(ctx.adapter_info.backend, wgpu::Backend::Gl),
        Some("vulkan") => assert_eq!(ctx.adapter_info.backend, wgpu::Backend::Vulkan),
        _ => {}
    }
    if let Ok(wg) = std::env::var(nimbus::gpu::shaders::WORKGROUP_ENV) {
        let wg: u32 = wg.parse().unwrap();
        let p = ctx.prelude;
        assert_eq!((p.wg_particles, p.wg_block, p.wg_scan), (wg, wg, wg));
    }
    assert_eq!(ctx.validation, nimbus::gpu::validation::requested());
    let caps = nimbus::gpu::limits::Caps::from_env().unwrap();
    if let Some(g) = caps.max_compute_workgroups_per_dimension {
        assert!(ctx.limits.max_compute_workgroups_per_dimension <= g);
        assert!(ctx.prelude.max_groups_x <= g);
        assert!(ctx.device.limits().max_compute_workgroups_per_dimension <= g);
    }
    if let Some(b) = caps.max_storage_buffer_binding_size {
        assert!(ctx.device.limits().max_storage_buffer_binding_size <= b);
    }
    let gl = GpuConfig {
        backend: Backend::Gl,
        ..GpuConfig::default()
    };
    if std::env::var("CI").as_deref() == Ok("true") {
        // .ci/run's OpenGL pass needs the EGL path tools/setup.sh installs
        Context::new(&gl).expect("OpenGL through EGL (tools/setup.sh: libegl1 libegl-mesa0)");
    }
}

fn tiny() -> ShotConfig {
    serde_saphyr::from_str(
        &std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/samples/tiny.yaml"))
            .unwrap(),
    )
    .unwrap()
}

/// Every stage dispatched with at most `m` workgroups per dimension, so that the larger
/// dispatches fold into rows along y (host-sized and GPU-written indirect ones alike): a frame
/// of the adaptive tiny shot (split, merge, smoothing, thermodynamics) is byte-identical to the
/// unfolded one. This is the path a dispatch over 65,535 workgroups takes on every adapter.
#[test]
fn folded_dispatches_give_the_same_frames() {
    let mut cfg = tiny();
    // supersaturated from the start: cloud condenses at once, so particles split (and, with
    // the merge threshold close below, some merge back) in the first frames
    cfg.physics.initial_vapor = 1.1;
    cfg.adaptive.split_threshold = 0.3;
    cfg.adaptive.merge_threshold = 0.25;
    let run = |ctx: Context| {
        let mut sim = Simulation::new(Arc::new(ctx), &prepared(&cfg)).unwrap();
        sim.step_frame().unwrap();
        sim.state().unwrap()
    };
    let unfolded = context();
    let wg = unfolded.prelude.wg_particles;
    let n = nimbus::config::lattice_count(&cfg.domain);
    let capacity = (n * cfg.adaptive.capacity_factor).ceil() as u32;
    // the largest dispatch (one thread per slot) needs `groups`; rows of m fold it
    let groups = capacity.div_ceil(wg);
    let m = (groups as f64).sqrt().ceil() as u32 + 1;
    assert!(m < groups, "{m} {groups}");
    let mut folded = context();
    folded.prelude.max_groups_x = m;
    let a = run(unfolded);
    let b = run(folded);
    assert!(a.len() > 1000);
    assert_eq!(a.len(), b.len());
    let bytes = |s: &nimbus::ground::ParticleState| {
        [
            bytemuck::cast_slice::<_, u8>(&s.pos).to_vec(),
            bytemuck::cast_slice::<_, u8>(&s.vel).to_vec(),
            bytemuck::cast_slice::<_, u8>(&s.thermo).to_vec(),
            bytemuck::cast_slice::<_, u8>(&s.info).to_vec(),
        ]
    };
    assert!(
        bytes(&a) == bytes(&b),
        "frames differ with dispatches folded into rows of {m} workgroups"
    );
    let split = a.info.iter().filter(|i| i[1] > 0).count();
    eprintln!(
        "{} particles ({split} split), dispatches folded into rows of {m} workgroups: identical",
        a.len()
    );
    assert!(
        split > 0,
        "no particle split: the adaptive kernels ran on nothing"
    );
}
