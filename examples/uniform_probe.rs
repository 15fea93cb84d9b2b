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
use wgpu::util::DeviceExt;

mod probe;

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
    let n = probe::arg(1, 100_000).max(64);
    let rounds = probe::arg(2, 8).max(1);
    let (adapter, device, queue) = probe::device(wgpu::Features::SUBGROUP);
    println!("adapter: {}, {n} invocations", adapter.get_info().name);
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
    let mut source = SHADER.to_string();
    for (name, index) in VARIANTS {
        source += &ENTRY.replace("NAME", name).replace("INDEX", index);
    }
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: None,
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let names: Vec<&str> = VARIANTS.iter().map(|v| v.0).collect();
    for group in [8u32, 4, 1] {
        let prm = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::cast_slice(&[n, group, 2000u32, 74]),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind = |binding, resource| wgpu::BindGroupEntry { binding, resource };
        let pipelines = probe::pipelines(
            &device,
            &module,
            &names,
            &[
                bind(0, table.as_entire_binding()),
                bind(1, outp.as_entire_binding()),
                bind(2, prm.as_entire_binding()),
            ],
        );
        for (name, ms, k) in probe::time(&device, &queue, &pipelines, n.div_ceil(64), rounds) {
            println!("group {group}: {name:>15}: {ms:7.3} ms per dispatch (median of {k})");
        }
    }
}
