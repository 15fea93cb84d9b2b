//! What the micro-probes of examples/ share: the Vulkan device, and the timing of a set of
//! compute pipelines over one dispatch shape (each pipeline 20 dispatches per round, rounds
//! alternated, the first one a warm-up; medians printed).
use std::time::Instant;

/// The first Vulkan adapter's device with `features`; exits 4 if there is none or it lacks them.
pub fn device(features: wgpu::Features) -> (wgpu::Adapter, wgpu::Device, wgpu::Queue) {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let Some(adapter) =
        pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN)).pop()
    else {
        eprintln!("error: no Vulkan adapter");
        std::process::exit(4);
    };
    if !adapter.features().contains(features) {
        eprintln!("error: the adapter lacks {features:?}");
        std::process::exit(4);
    }
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: None,
        required_features: features,
        required_limits: adapter.limits(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .expect("device");
    (adapter, device, queue)
}

/// Positional argument `k` as a u32, `default` if absent or not a number.
pub fn arg(k: usize, default: u32) -> u32 {
    std::env::args()
        .nth(k)
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Median ms per dispatch of each (name, pipeline, bind group), `workgroups` workgroups each.
pub fn time(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    pipelines: &[(&str, wgpu::ComputePipeline, wgpu::BindGroup)],
    workgroups: u32,
    rounds: u32,
) -> Vec<(String, f64, usize)> {
    let reps = 20;
    let mut times = vec![Vec::new(); pipelines.len()];
    for round in 0..rounds {
        for (v, (_, p, group)) in pipelines.iter().enumerate() {
            let mut enc = device.create_command_encoder(&Default::default());
            for _ in 0..reps {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(p);
                pass.set_bind_group(0, group, &[]);
                pass.dispatch_workgroups(workgroups, 1, 1);
            }
            let t = Instant::now();
            queue.submit([enc.finish()]);
            device
                .poll(wgpu::PollType::wait_indefinitely())
                .expect("poll");
            // the first round compiles and warms up
            if round > 0 || rounds == 1 {
                times[v].push(t.elapsed().as_secs_f64() * 1e3 / f64::from(reps));
            }
        }
    }
    pipelines
        .iter()
        .zip(times)
        .map(|((name, _, _), mut t)| {
            t.sort_by(f64::total_cmp);
            (name.to_string(), t[t.len() / 2], t.len())
        })
        .collect()
}

/// One compute pipeline per entry point of `module`, each with `entries` bound at group 0.
pub fn pipelines<'a>(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    names: &[&'a str],
    entries: &[wgpu::BindGroupEntry<'_>],
) -> Vec<(&'a str, wgpu::ComputePipeline, wgpu::BindGroup)> {
    names
        .iter()
        .map(|&name| {
            let p = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: None,
                layout: None,
                module,
                entry_point: Some(name),
                compilation_options: Default::default(),
                cache: None,
            });
            let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &p.get_bind_group_layout(0),
                entries,
            });
            (name, p, group)
        })
        .collect()
}
