//! Whether a load whose index is the same in every lane of a subgroup costs less than a gather
//! on this adapter, when the shader says so (`subgroupBroadcastFirst`):
//! `cargo run --release --example uniform_probe -- [PARTICLES] [ROUNDS]`.
//!
//! The PBF passes load 18 cell-table entries per particle (9 rows, two ends each) at indices
//! the particle's anchor gives; consecutive particles mostly share their cell, so the 8 lanes of
//! a SIMD batch on llvmpipe load the same 18 addresses. Each variant runs 18 such loads per
//! invocation, with the row index a function of `i / GROUP` (GROUP consecutive invocations share
//! it), and a poly6-like term of the loaded value:
//! - `lane_index`: the index as computed (the compiler cannot know it is uniform: a gather);
//! - `broadcast_index`: the index through `subgroupBroadcastFirst`, with a per-lane fallback
//!   when not every lane agrees (`subgroupAll`);
//! - `constant_index`: one fixed row (no dependent load: the floor).
use std::time::Instant;
use wgpu::util::DeviceExt;

const SHADER: &str = r#"
@group(0) @binding(0) var<storage, read> table: array<u32>;
@group(0) @binding(1) var<storage, read_write> outp: array<u32>;
struct P { n: u32, group: u32, plane: u32, row: u32 }
@group(0) @binding(2) var<uniform> prm: P;

fn hash(x: u32) -> u32 {
    var h = x * 747796405u + 2891336453u;
    h = ((h >> ((h >> 28u) + 4u)) ^ h) * 277803737u;
    return (h >> 22u) ^ h;
}
// row r's first entry for the cell of invocation i
fn row_index(c: u32, r: u32) -> u32 {
    let dz = i32(r / 3u) - 1;
    let dy = i32(r % 3u) - 1;
    let j = i32(c * 7u) + dz * i32(prm.plane) + dy * i32(prm.row);
    return u32(clamp(j, 0, i32(prm.n) - 2));
}
"#;

const ENTRY: &str = r#"
@compute @workgroup_size(64)
fn NAME(@builtin(global_invocation_id) g: vec3<u32>) {
    let i = g.x;
    if (i >= prm.n) { return; }
    let c = (i / prm.group) % (prm.n / 8u);
    var acc = 0u;
    for (var r = 0u; r < 9u; r++) {
        let base = row_index(c, r);
        INDEX
        let a = table[e];
        let b = table[e + 1u];
        acc += (a ^ b) + hash(a + r);
    }
    outp[i] = acc;
}
"#;

const VARIANTS: [(&str, &str); 3] = [
    ("lane_index", "let e = base;"),
    (
        "broadcast_index",
        "let first = subgroupBroadcastFirst(base); var e = base; if (subgroupAll(base == first)) { e = first; }",
    ),
    ("constant_index", "let e = row_index(0u, r);"),
];

fn main() {
    let arg = |k: usize, d: u32| {
        std::env::args()
            .nth(k)
            .and_then(|s| s.parse().ok())
            .unwrap_or(d)
    };
    let n = arg(1, 100_000).max(64);
    let rounds = arg(2, 8).max(1);
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let Some(adapter) =
        pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN)).pop()
    else {
        eprintln!("error: no Vulkan adapter");
        std::process::exit(4);
    };
    if !adapter.features().contains(wgpu::Features::SUBGROUP) {
        eprintln!("error: the adapter has no subgroup operations");
        std::process::exit(4);
    }
    println!("adapter: {}, {n} invocations", adapter.get_info().name);
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: None,
        required_features: wgpu::Features::SUBGROUP,
        required_limits: adapter.limits(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    }))
    .expect("device");
    let values: Vec<u32> = (0..n).map(|i| i.wrapping_mul(2654435761)).collect();
    let table = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&values),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let outp = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: u64::from(n) * 4,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    for group in [8u32, 4, 1] {
        let prm = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::cast_slice(&[n, group, 2000u32, 74]),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let mut source = SHADER.to_string();
        for (name, index) in VARIANTS {
            source += &ENTRY.replace("NAME", name).replace("INDEX", index);
        }
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: None,
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipelines: Vec<_> = VARIANTS
            .iter()
            .map(|(entry, _)| {
                let p = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: None,
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                });
                let bind = |binding, resource| wgpu::BindGroupEntry { binding, resource };
                let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: None,
                    layout: &p.get_bind_group_layout(0),
                    entries: &[
                        bind(0, table.as_entire_binding()),
                        bind(1, outp.as_entire_binding()),
                        bind(2, prm.as_entire_binding()),
                    ],
                });
                (p, group)
            })
            .collect();
        let reps = 20;
        let mut times = vec![Vec::new(); VARIANTS.len()];
        for round in 0..rounds {
            for (v, (p, bg)) in pipelines.iter().enumerate() {
                let mut enc = device.create_command_encoder(&Default::default());
                for _ in 0..reps {
                    let mut pass = enc.begin_compute_pass(&Default::default());
                    pass.set_pipeline(p);
                    pass.set_bind_group(0, bg, &[]);
                    pass.dispatch_workgroups(n.div_ceil(64), 1, 1);
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
        for ((name, _), mut t) in VARIANTS.iter().zip(times) {
            t.sort_by(f64::total_cmp);
            println!(
                "group {group}: {name:>15}: {:7.3} ms per dispatch (median of {})",
                t[t.len() / 2],
                t.len()
            );
        }
    }
}
