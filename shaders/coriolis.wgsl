// The Coriolis force about a geostrophic wind and the surface stress (`physics.wind.coriolis`,
// `physics.wind.surface_friction`), per particle, at the start of every substep, before the
// PBF prediction takes the external forces.
// - Coriolis: the horizontal velocity's departure from the geostrophic wind U_g(y) turns by f dt,
//   du_h/dt = -f y x (u_h - U_g) solved exactly over dt (y up, so with f > 0 the air turns to
//   the right of its motion seen from above, and north is -z).
// - Surface stress: below the surface layer's depth d the velocity over the ground loses
//   dt u*^2 / d of its speed, never more than it has.
// f64 mirror: src/sim/reference/coriolis.rs (`apply_coriolis`). No neighbours are read.
//!include shared/common.wgsl

// Mirror of sim::forces::coriolis::CoriolisParams (byte for byte).
struct CoriolisParams {
    // cos and sin of the turn f dt of the substep
    turn_cos: f32,
    turn_sin: f32,
    // levels of the geostrophic wind (0 = no Coriolis force: the drag alone)
    n_levels: u32,
    // particles below this height take the surface stress (m)
    surface_layer: f32,
    // the speed the surface stress takes off in the substep, dt u*^2 / d (m/s)
    drag: f32,
    _pad0: u32,
    // the ground's velocity in the shot's frame (x, z)
    ground: vec2<f32>,
    // (height m, speed m/s, heading rad unwrapped along the profile, -) by increasing height
    levels: array<vec4<f32>, MAX_WIND_LEVELS>,
}

@group(0) @binding(0) var<uniform> C: CoriolisParams;
@group(0) @binding(1) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> live: Live;

// The geostrophic wind (u_x, u_z) at height y: speed and heading linear between levels,
// constant outside them (the lookup of thermo.wgsl's `wind_at`; mirror:
// sim::reference::thermo::profile_wind).
fn geostrophic_at(y: f32) -> vec2<f32> {
    var a = C.levels[0];
    var b = a;
    for (var k = 1u; k < C.n_levels; k++) {
        b = C.levels[k];
        if (y < b.x) { break; }
        a = b;
    }
    var t = 0.0;
    if (b.x > a.x) { t = clamp((y - a.x) / (b.x - a.x), 0.0, 1.0); }
    let speed = mix(a.y, b.y, t);
    let heading = mix(a.z, b.z, t);
    return speed * vec2<f32>(cos(heading), sin(heading));
}

@compute @workgroup_size(WG_PARTICLES)
fn apply_coriolis(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let y = pos[i].y;
    let v = vel[i];
    var u = v.xz;
    if (C.n_levels > 0u) {
        let g = geostrophic_at(y);
        let a = u - g;
        u = g + vec2<f32>(C.turn_cos * a.x - C.turn_sin * a.y, C.turn_sin * a.x + C.turn_cos * a.y);
    }
    if (y < C.surface_layer && C.drag > 0.0) {
        let over_ground = u - C.ground;
        let speed = length(over_ground);
        if (speed > 0.0) {
            u = u - over_ground * min(C.drag / speed, 1.0);
        }
    }
    vel[i] = vec4<f32>(u.x, v.y, u.y, v.w);
}
