//! What a neighbour gather costs on this adapter, by where the neighbour's data comes from
//! (docs/PERFORMANCE.md "PBF / Session 15"):
//! `cargo run --release --example gather_probe -- [PARTICLES] [ROUNDS]`.
//!
//! Every variant runs the same loop: per particle, 33-40 neighbours at PBF-like index offsets
//! (9 rows: the particle's own, +-1 row, +-1 plane, each +-8 around it), a poly6-like term per
//! neighbour. Only the neighbour's load differs: one vec4 from a storage buffer (or only its
//! xyz), one vec2 (a packed position), three f32 loads, a `textureLoad` from an rgba32float
//! texture, a load from workgroup memory staged from the buffer (after a barrier), or no load
//! at all (the loop and the arithmetic alone). Prints the median ms per dispatch of each.
use wgpu::util::DeviceExt;

mod probe;

const SHADER: &str = r#"
@group(0) @binding(0) var<storage, read> data: array<vec4<f32>>;
@group(0) @binding(1) var<storage, read_write> outp: array<vec4<f32>>;
@group(0) @binding(2) var tex: texture_2d<f32>;
struct P { n: u32, plane: u32, row: u32, logw: u32 }
@group(0) @binding(3) var<uniform> prm: P;
// the same buffer as `data`, viewed as vec2 and as f32
@group(0) @binding(4) var<storage, read> data2: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> data1: array<f32>;
var<workgroup> tile: array<vec4<f32>, 1024>;

fn hash(x: u32) -> u32 {
    var h = x * 747796405u + 2891336453u;
    h = ((h >> ((h >> 28u) + 4u)) ^ h) * 277803737u;
    return (h >> 22u) ^ h;
}
fn count(i: u32) -> u32 { return 33u + (hash(i) & 7u); }
fn neighbour(i: u32, k: u32) -> u32 {
    let r = k % 9u;
    let dz = i32(r / 3u) - 1;
    let dy = i32(r % 3u) - 1;
    let j = i32(i) + dz * i32(prm.plane) + dy * i32(prm.row) + i32(hash(i * 64u + k) & 15u) - 8;
    return u32(clamp(j, 0, i32(prm.n) - 1));
}
fn term(me: vec4<f32>, pj: vec4<f32>) -> vec4<f32> {
    let d = me.xyz - pj.xyz;
    let w = max(0.01 - dot(d, d), 0.0);
    return vec4<f32>(d * w * w, pj.w * w);
}
// binds every resource in every entry point (one bind group layout for all)
fn me_of(i: u32) -> vec4<f32> {
    var me = data[i] + vec4<f32>(f32(data2[i].x) * 0.0 + data1[i] * 0.0);
    if (prm.n == 0u) { me += textureLoad(tex, vec2<u32>(0u), 0); }
    return me;
}
// 21 bits per axis in two words, as a packed position would be
fn packed(j: u32) -> vec4<f32> {
    let q = data2[j];
    let p = vec3<u32>(q.x & 0x1fffffu, (q.x >> 21u) | ((q.y & 0x3ffu) << 11u), q.y >> 10u);
    return vec4<f32>(vec3<f32>(p) * 1e-7, 1.0);
}
fn texel(j: u32) -> vec4<f32> {
    let m = (1u << prm.logw) - 1u;
    return textureLoad(tex, vec2<u32>(j & m, j >> prm.logw), 0);
}
// staged by the workgroup behind a barrier
fn stage(base: u32, l: u32) {
    for (var k = 0u; k < 16u; k++) { tile[k * 64u + l] = data[min(base + k * 64u + l, prm.n - 1u)]; }
    workgroupBarrier();
}
"#;

/// One entry point per variant: `PROLOGUE` runs first in every invocation, `LOAD` is the
/// neighbour j's data.
const ENTRY: &str = r#"
@compute @workgroup_size(64)
fn NAME(@builtin(global_invocation_id) g: vec3<u32>, @builtin(local_invocation_index) l: u32,
        @builtin(workgroup_id) wg: vec3<u32>) {
    PROLOGUE
    let i = g.x;
    if (i >= prm.n) { return; }
    let me = me_of(i);
    var acc = vec4<f32>(0.0);
    for (var k = 0u; k < count(i); k++) {
        let j = neighbour(i, k);
        acc += term(me, LOAD);
    }
    outp[i] = acc;
}
"#;

/// (entry point, prologue, the neighbour's load)
const VARIANTS: [(&str, &str, &str); 7] = [
    ("buffer_vec4", "", "data[j]"),
    ("buffer_xyz", "", "vec4<f32>(data[j].xyz, 1.0)"),
    ("buffer_vec2", "", "packed(j)"),
    (
        "buffer_3xf32",
        "",
        "vec4<f32>(data1[4u * j], data1[4u * j + 1u], data1[4u * j + 2u], 1.0)",
    ),
    ("texture_load", "", "texel(j)"),
    ("workgroup_tile", "stage(wg.x * 64u, l);", "tile[j & 1023u]"),
    ("no_load", "", "vec4<f32>(f32(j) * 1e-6, me.y, me.z, 1.0)"),
];

fn main() {
    let n = probe::arg(1, 100_000).max(64);
    let rounds = probe::arg(2, 8).max(1);
    let (adapter, device, queue) = probe::device(wgpu::Features::empty());
    println!("adapter: {}, {n} particles", adapter.get_info().name);
    let logw = 10u32;
    let (w, h) = (1u32 << logw, n.div_ceil(1 << logw));
    let values: Vec<f32> = (0..w * h)
        .flat_map(|i| {
            let f = i as f32;
            [(f * 0.37).sin(), (f * 0.11).cos(), (f * 0.07).sin(), 20.0].map(|v| v * 0.05)
        })
        .collect();
    let data = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&values),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let outp = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: u64::from(w * h) * 16,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let tex = device.create_texture_with_data(
        &queue,
        &wgpu::TextureDescriptor {
            label: None,
            size: wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(&values),
    );
    let view = tex.create_view(&Default::default());
    // a block scene's plane and row of cell entries at 100k, in particles
    let prm = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: None,
        contents: bytemuck::cast_slice(&[n, 2000u32, 74, logw]),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let mut source = SHADER.to_string();
    for (name, prologue, load) in VARIANTS {
        source += &ENTRY
            .replace("NAME", name)
            .replace("PROLOGUE", prologue)
            .replace("LOAD", load);
    }
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: None,
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let bind = |binding, resource| wgpu::BindGroupEntry { binding, resource };
    let names: Vec<&str> = VARIANTS.iter().map(|v| v.0).collect();
    let pipelines = probe::pipelines(
        &device,
        &module,
        &names,
        &[
            bind(0, data.as_entire_binding()),
            bind(1, outp.as_entire_binding()),
            bind(2, wgpu::BindingResource::TextureView(&view)),
            bind(3, prm.as_entire_binding()),
            bind(4, data.as_entire_binding()),
            bind(5, data.as_entire_binding()),
        ],
    );
    for (name, ms, k) in probe::time(&device, &queue, &pipelines, n.div_ceil(64), rounds) {
        println!("{name:>15}: {ms:7.2} ms per dispatch (median of {k})");
    }
}
