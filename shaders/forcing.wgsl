// The large-scale forcing of an atmospheric case (`physics.forcing`), once a frame, per
// particle, before the frame's first substep moves anything: radiation, the moisture tendency
// and the subsidence of the horizontal means from the host's layer table, and the surface
// fluxes in the surface layer. One step of the frame's length, because per substep of a few
// seconds a radiative cooling of 2 K/day is about one f32 ulp of 300 K.
// Both are added with `add_unbiased` (shared/common.wgsl).
// f64 mirror: src/sim/reference/forcing.rs (`apply_forcing`), the exact sums. No neighbours
// are read.
//!include shared/common.wgsl

// Mirror of sim::forces::forcing::ForcingParams (byte for byte).
struct ForcingParams {
    // the frame's length (s)
    dt: f32,
    // layers of the table (>= 1) and their height (m); the table holds each layer centre's
    // (dT/dt K/s, dq/dt kg/kg/s), linear between centres, constant beyond the outer ones
    n_layers: u32,
    layer_height: f32,
    // particles below this height take the surface fluxes (m)
    surface_layer: f32,
    // the surface fluxes over the surface layer's depth: (K/s, kg/kg/s)
    surface_heat: f32,
    surface_moisture: f32,
    _pad0: u32,
    _pad1: u32,
    layers: array<vec4<f32>, MAX_FORCING_LAYERS>,
}

@group(0) @binding(0) var<uniform> F: ForcingParams;
@group(0) @binding(1) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> live: Live;

// The table's (dT/dt, dq/dt) at height y (mirror: sim::reference::forcing::table_at).
fn table_at(y: f32) -> vec2<f32> {
    let t = clamp(y / F.layer_height - 0.5, 0.0, f32(F.n_layers - 1u));
    let k0 = u32(floor(t));
    let k1 = min(k0 + 1u, F.n_layers - 1u);
    return mix(F.layers[k0].xy, F.layers[k1].xy, t - f32(k0));
}

@compute @workgroup_size(WG_PARTICLES)
fn apply_forcing(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let y = pos[i].y;
    var rate = table_at(y);
    if (y < F.surface_layer) {
        rate = rate + vec2<f32>(F.surface_heat, F.surface_moisture);
    }
    let th = thermo[i];
    // the vapor cannot go below zero (a drying larger than what is there takes what is there)
    // every particle of the surface layer takes nearly the same increment, which a plain f32
    // sum rounds the same way for all of them (0.9% of the BOMEX shot's heat budget)
    let key = state_key(pos[i].xyz, pcg_hash(bitcast<u32>(th.x)));
    let t_new = add_unbiased(th.x, F.dt * rate.x, key);
    let v_new = max(add_unbiased(th.y, F.dt * rate.y, pcg_hash(key)), 0.0);
    thermo[i] = vec4<f32>(t_new, v_new, th.z, th.w);
}
