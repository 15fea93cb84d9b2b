// Gather of a particle array into cell order (dst[i] = src[order[i]]), and a plain copy.
// Mirror: src/sim/reference/permute.rs.
// A template (WGSL has no generics): src/gpu/shaders.rs builds the stages permute4.wgsl
// (ELEM = vec4<f32>, entry points permute4/copy4) and permute2.wgsl (vec2<u32>, permute2/copy2)
// from it by replacing ELEM and WIDTH.
//!include shared/common.wgsl

@group(0) @binding(0) var<storage, read> live: Live;
@group(0) @binding(1) var<storage, read_write> order: array<u32>;
@group(0) @binding(2) var<storage, read_write> src: array<ELEM>;
@group(0) @binding(3) var<storage, read_write> dst: array<ELEM>;

@compute @workgroup_size(WG_PARTICLES)
fn permuteWIDTH(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    dst[i] = src[order[i]];
}

@compute @workgroup_size(WG_PARTICLES)
fn copyWIDTH(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    dst[i] = src[i];
}
