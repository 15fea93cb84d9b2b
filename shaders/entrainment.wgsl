// The clouds' entrainment (`physics.entrainment`), once a frame, per particle, before the
// frame's first substep moves anything. A cloudy particle (w > 0) mixes with the clear air of
// its height a fraction r = 1 - exp(-epsilon |u_y| dt) of the way: T, v and w each move by r
// towards the clear air's (T_env = <s_l>_env - Gamma_d y, v_env = <q_t>_env, no cloud water),
// which moves its s_l and q_t by r towards the clear air's means; the phase transition of the
// next substep then evaporates what the mixture cannot hold. A clear particle takes the
// clouds' loss of its layers, per unit mass, from the host's table, so that the pass keeps the
// mass-weighted sums of s_l and q_t (the vapor floor aside), on average also where the gain is
// below an f32 ulp (`add_unbiased`, shared/common.wgsl).
// f64 mirror: src/sim/reference/entrainment.rs (`apply_entrainment`). No neighbours are read.
//!include shared/common.wgsl

// Mirror of sim::forces::entrainment::EntrainmentParams (byte for byte).
struct EntrainmentParams {
    // the frame's length (s) and the entrainment rate epsilon (1/m)
    dt: f32,
    rate: f32,
    // layers of the table (>= 1) and their height (m): each particle reads the two layer
    // centres around it, linearly, clamped at the outer ones
    n_layers: u32,
    layer_height: f32,
    // Gamma_d (K/m): the clear air's T at y is its s_l - Gamma_d y (it holds no cloud water)
    lapse: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    // per layer: the clear air's mean s_l (K) and q_t (kg/kg), and 1 where the layer holds
    // clear air (0: its clouds have none to mix with there)
    env: array<vec4<f32>, MAX_FORCING_LAYERS>,
    // per layer: the gain of s_l (K) and q_t (kg/kg) of each clear particle of the layer
    gain: array<vec4<f32>, MAX_FORCING_LAYERS>,
}

@group(0) @binding(0) var<uniform> E: EntrainmentParams;
@group(0) @binding(1) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> vel: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> live: Live;

@compute @workgroup_size(WG_PARTICLES)
fn apply_entrainment(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let y = pos[i].y;
    let t = clamp(y / E.layer_height - 0.5, 0.0, f32(E.n_layers - 1u));
    let k0 = u32(floor(t));
    let k1 = min(k0 + 1u, E.n_layers - 1u);
    let f = t - f32(k0);
    let th = thermo[i];
    if (th.z > 0.0) {
        // the clear air at y, from the layers that hold some
        let a = (1.0 - f) * E.env[k0].z;
        let b = f * E.env[k1].z;
        if (a + b <= 0.0) { return; }
        let env = (a * E.env[k0].xy + b * E.env[k1].xy) / (a + b);
        let r = 1.0 - exp(-E.rate * abs(vel[i].y) * E.dt);
        let t_env = env.x - E.lapse * y;
        thermo[i] = vec4<f32>(th.x - r * (th.x - t_env), th.y - r * (th.y - env.y), th.z - r * th.z, th.w);
    } else {
        let g = mix(E.gain[k0].xy, E.gain[k1].xy, f);
        let key = state_key(pos[i].xyz, 0u);
        let t_new = add_unbiased(th.x, g.x, key);
        let v_new = max(add_unbiased(th.y, g.y, pcg_hash(key)), 0.0);
        thermo[i] = vec4<f32>(t_new, v_new, th.z, th.w);
    }
}
