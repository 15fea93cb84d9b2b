//! Every stage's SPIR-V, as naga writes it for wgpu's Vulkan backend, passes `spirv-val` (the
//! Khronos SPIR-V validator, Debian `spirv-tools`) under the Vulkan environment it is made for.
//! A driver is free to reject invalid SPIR-V that lavapipe happens to run; this finds it here.
//!
//! The SPIR-V is written as wgpu-hal 30 writes it at pipeline creation
//! (`wgpu_hal::vulkan::Device::compile_stage`): one module per entry point, overrides
//! resolved, the SPIR-V version wgpu picks for the device's Vulkan version (1.1: 1.3, 1.2: 1.5,
//! 1.3 and later: 1.6), its capabilities, bounds-check and workgroup-memory policies, and
//! nimbus's runtime checks (all on but the forced loop bound, `gpu::shaders::module`). Every
//! prelude is written: the GPU one, the CPU one (lavapipe's scan shape and loop budget) and
//! each workgroup size `NIMBUS_GPU_WORKGROUP` may force.
//!
//! Without spirv-val the test is skipped with a note; under CI=true (.ci/run, whose
//! tools/setup.sh installs spirv-tools) it fails.
mod common;

use naga::back::spv;
use nimbus::gpu::shaders::{self, Prelude};
use std::process::Command;

/// One Vulkan environment: the validator's target, the SPIR-V version wgpu writes for it, and
/// the policies of a driver of that age (robustBufferAccess2 and zero-initialised workgroup
/// memory came with Vulkan 1.3-era drivers).
struct Env {
    target: &'static str,
    lang: (u8, u8),
    buffer_checks: naga::proc::BoundsCheckPolicy,
    zero_init: spv::ZeroInitializeWorkgroupMemoryMode,
}

const ENVS: [Env; 3] = [
    Env {
        target: "vulkan1.1",
        lang: (1, 3),
        buffer_checks: naga::proc::BoundsCheckPolicy::Restrict,
        zero_init: spv::ZeroInitializeWorkgroupMemoryMode::Polyfill,
    },
    Env {
        target: "vulkan1.2",
        lang: (1, 5),
        buffer_checks: naga::proc::BoundsCheckPolicy::Restrict,
        zero_init: spv::ZeroInitializeWorkgroupMemoryMode::Polyfill,
    },
    Env {
        target: "vulkan1.3",
        lang: (1, 6),
        buffer_checks: naga::proc::BoundsCheckPolicy::Unchecked,
        zero_init: spv::ZeroInitializeWorkgroupMemoryMode::Native,
    },
];

/// The binding map wgpu-hal makes from a pipeline layout: Vulkan numbers each group's bindings
/// densely in the layout's order (nimbus's layouts hold every binding of the stage's file,
/// sorted, `gpu::program::reflect`).
fn binding_map(module: &naga::Module) -> spv::BindingMap {
    let mut bindings: Vec<naga::ResourceBinding> = module
        .global_variables
        .iter()
        .filter_map(|(_, v)| v.binding)
        .collect();
    bindings.sort_by_key(|b| (b.group, b.binding));
    let mut map = spv::BindingMap::default();
    let mut next = (u32::MAX, 0);
    for b in bindings {
        if next.0 != b.group {
            next = (b.group, 0);
        }
        map.insert(
            b,
            spv::BindingInfo {
                descriptor_set: b.group,
                binding: next.1,
                binding_array_size: None,
            },
        );
        next.1 += 1;
    }
    map
}

/// The options wgpu-hal gives naga's SPIR-V writer for a device of `env`.
fn options(env: &Env, binding_map: spv::BindingMap) -> spv::Options<'static> {
    use spv::Capability as C;
    let capabilities = [
        C::Shader,
        C::Matrix,
        C::Sampled1D,
        C::Image1D,
        C::ImageQuery,
        C::DerivativeControl,
        C::StorageImageExtendedFormats,
        C::SampledCubeArray,
        C::SampleRateShading,
    ];
    spv::Options {
        lang_version: env.lang,
        flags: spv::WriterFlags::DEBUG
            | spv::WriterFlags::LABEL_VARYINGS
            | spv::WriterFlags::FORCE_POINT_SIZE,
        capabilities: Some(capabilities.into_iter().collect()),
        bounds_check_policies: naga::proc::BoundsCheckPolicies {
            index: naga::proc::BoundsCheckPolicy::Restrict,
            buffer: env.buffer_checks,
            image_load: naga::proc::BoundsCheckPolicy::Restrict,
            binding_array: naga::proc::BoundsCheckPolicy::Unchecked,
        },
        zero_initialize_workgroup_memory: env.zero_init,
        // nimbus turns the forced loop bound off (gpu::shaders::module)
        force_loop_bounding: false,
        fake_missing_bindings: false,
        binding_map,
        ..spv::Options::default()
    }
}

#[test]
fn every_entry_point_passes_spirv_val() {
    if !common::spirv_val_available() {
        eprintln!("skipped: spirv-val not found (apt-get install spirv-tools)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut preludes = vec![
        ("gpu".to_string(), Prelude::default()),
        (
            "cpu".to_string(),
            Prelude {
                wg_scan: shaders::WG_SCAN_CPU,
                loop_budget: shaders::CPU_LOOP_BUDGET,
                ..Prelude::default()
            },
        ),
    ];
    // the workgroup sizes NIMBUS_GPU_WORKGROUP forces
    for wg in shaders::FORCEABLE_WORKGROUPS {
        preludes.push((format!("wg{wg}"), Prelude::default().with_workgroup(wg)));
    }
    let mut constants = naga::back::PipelineConstants::default();
    constants.insert("SCORR_N".to_string(), 4.0);
    let mut jobs = Vec::new();
    for name in shaders::program_names() {
        for (tag, prelude) in &preludes {
            let module = shaders::validate_with(name, prelude).unwrap_or_else(|e| panic!("{e}"));
            let info = naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap();
            let bindings = binding_map(&module);
            // the constants a stage declares (PBF's SCORR_N), as Program::with_constants gives them
            let mut own = naga::back::PipelineConstants::default();
            for (_, o) in module.overrides.iter() {
                let name = o.name.clone().unwrap_or_default();
                let value = constants.get(&name).unwrap_or_else(|| panic!("{name}?"));
                own.insert(name, *value);
            }
            for ep in &module.entry_points {
                let (module, info) = naga::back::pipeline_constants::process_overrides(
                    &module,
                    &info,
                    Some((naga::ShaderStage::Compute, &ep.name)),
                    &own,
                )
                .unwrap_or_else(|e| panic!("{name}:{}: overrides: {e}", ep.name));
                for env in &ENVS {
                    let pipeline = spv::PipelineOptions {
                        shader_stage: naga::ShaderStage::Compute,
                        entry_point: ep.name.clone(),
                    };
                    let words = spv::write_vec(
                        &module,
                        &info,
                        &options(env, bindings.clone()),
                        Some(&pipeline),
                    )
                    .unwrap_or_else(|e| panic!("{name}:{}: naga: {e}", ep.name));
                    let file = dir.path().join(format!(
                        "{}.{}.{tag}.{}.spv",
                        name.trim_end_matches(".wgsl"),
                        ep.name,
                        env.target
                    ));
                    std::fs::write(&file, bytemuck::cast_slice::<u32, u8>(&words)).unwrap();
                    jobs.push((file, env.target));
                }
            }
        }
    }
    assert!(jobs.len() > 100, "only {} modules written", jobs.len());
    // spirv-val takes one module per call; two threads halve the wait on CI's two cores
    let failures: Vec<String> = std::thread::scope(|s| {
        let handles: Vec<_> = jobs
            .chunks(jobs.len().div_ceil(2))
            .map(|chunk| {
                s.spawn(move || {
                    chunk
                        .iter()
                        .filter_map(|(file, target)| {
                            let o = Command::new("spirv-val")
                                .args(["--target-env", target])
                                .arg(file)
                                .output()
                                .expect("spirv-val runs");
                            (!o.status.success()).then(|| {
                                format!(
                                    "{} ({target}): {}{}",
                                    file.file_name().unwrap().to_string_lossy(),
                                    String::from_utf8_lossy(&o.stdout),
                                    String::from_utf8_lossy(&o.stderr)
                                )
                            })
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    assert!(
        failures.is_empty(),
        "{} of {} modules fail spirv-val:\n{}",
        failures.len(),
        jobs.len(),
        failures.join("\n")
    );
    eprintln!("{} modules pass spirv-val", jobs.len());
}
