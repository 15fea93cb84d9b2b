// Cloud thermodynamics of one substep, per particle (paper section 4, in the paper's order
// after the PBF move and the temperature smoothing):
//   ground heating (eq. 5, and the ground's evaporation) -> buoyancy and cloud weight (eq. 6) -> adiabatic cooling (eq. 7)
//   -> phase transition (eqs. 8-10) -> latent heat (eq. 11).
// f64 mirror: src/sim/reference/thermo.rs (`thermo_step`); noise mirror: src/sim/noise.rs.
// No neighbours are read, so every particle is independent (deterministic).
//!include shared/common.wgsl

// Mirror of sim::thermo::ThermoParams (byte for byte).
struct ThermoParams {
    dt: f32,
    time: f32,
    _pad0: u32,
    seed: u32,
    ground_temperature: f32,
    lapse_rate: f32,
    adiabatic_lapse_rate: f32,
    heat_source: f32,
    heat_height: f32,
    noise_cell_x: f32,
    noise_cell_z: f32,
    noise_speed: f32,
    noise_period_x: u32,
    noise_period_z: u32,
    noise_contrast: f32,
    buoyancy: f32,
    cloud_weight: f32,
    // 1 - exp(-alpha dt): the exact relaxation fraction of eq. 9 over one step (host computed).
    phase_fraction: f32,
    saturation_a: f32,
    saturation_b: f32,
    saturation_c: f32,
    latent_heat: f32,
    inversion_base: f32,
    inversion_depth: f32,
    inversion_strength: f32,
    lapse_above: f32,
    heat_noise: u32,
    n_sources: u32,
    size_x: f32,
    size_z: f32,
    periodic: u32,
    // layers of the horizontal-mean buoyancy profile (0 = none: physics.buoyancy_reference)
    n_layers: u32,
    // (centre x, centre z, radius, strength K/s)
    sources: array<vec4<f32>, 8>,
    layer_height: f32,
    // vapor per kelvin of ground heating, 1 / (Bowen ratio Q) (0 = dry ground)
    ground_vapor: f32,
    _pad2: u32,
    _pad3: u32,
    // the profile (m/s^2) at the layer centres, four a row (sim::thermo::LayerBuoyancy)
    layers: array<vec4<f32>, 8>,
}

@group(0) @binding(0) var<uniform> P: ThermoParams;
@group(0) @binding(1) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> thermo: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> live: Live;

// Lattice value in [0, 1): the top 24 bits are exact in f32, so GPU and mirror agree.
fn lattice_value(ix: i32, iz: i32, it: i32, seed: u32) -> f32 {
    let h = pcg_hash(bitcast<u32>(ix) ^ pcg_hash(bitcast<u32>(iz) ^ pcg_hash(bitcast<u32>(it) ^ pcg_hash(seed))));
    return f32(h >> 8u) * (1.0 / 16777216.0);
}

fn fade(u: f32) -> f32 {
    return u * u * u * (u * (u * 6.0 - 15.0) + 10.0);
}

fn wrap_index(i: i32, period: u32) -> i32 {
    let p = i32(max(period, 1u));
    return ((i % p) + p) % p;
}

// Value noise over (x, z) and time with quintic fade, tiling with the given lattice periods.
fn value_noise3(x: f32, z: f32, t: f32, cell_x: f32, cell_z: f32, period_x: u32, period_z: u32, seed: u32) -> f32 {
    let p = vec3<f32>(x / cell_x, z / cell_z, t);
    let f = floor(p);
    let u = vec3<f32>(fade(p.x - f.x), fade(p.y - f.y), fade(p.z - f.z));
    let i = vec3<i32>(f);
    let x0 = wrap_index(i.x, period_x);
    let x1 = wrap_index(i.x + 1, period_x);
    let z0 = wrap_index(i.y, period_z);
    let z1 = wrap_index(i.y + 1, period_z);
    var along_t: array<f32, 2>;
    for (var dt = 0; dt < 2; dt++) {
        let it = i.z + dt;
        let a = mix(lattice_value(x0, z0, it, seed), lattice_value(x1, z0, it, seed), u.x);
        let b = mix(lattice_value(x0, z1, it, seed), lattice_value(x1, z1, it, seed), u.x);
        along_t[dt] = mix(a, b, u.y);
    }
    return mix(along_t[0], along_t[1], u.z);
}

// Fraction in [0, 1] of the heat source at ground point (x, z): the noise around 0.5 stretched
// by the contrast and clamped, so contrast > 1 gives distinct hot patches and cold gaps.
fn heat_factor(x: f32, z: f32, time: f32) -> f32 {
    let n = value_noise3(x, z, time * P.noise_speed, P.noise_cell_x, P.noise_cell_z,
        P.noise_period_x, P.noise_period_z, P.seed);
    return clamp((n - 0.5) * P.noise_contrast + 0.5, 0.0, 1.0);
}

// Shortest signed distance along a periodic axis (bit set) of extent s.
fn wrap_delta(d: f32, s: f32, periodic: bool) -> f32 {
    return select(d, d - s * round(d / s), periodic);
}

// Heating rate (K/s) at ground point (x, z): the noise pattern and the disc sources
// (mirror: sim::reference::thermo::heating_rate; falloff: HeatSource::falloff).
fn heating_rate(x: f32, z: f32, time: f32) -> f32 {
    var rate = 0.0;
    if (P.heat_noise != 0u) { rate = P.heat_source * heat_factor(x, z, time); }
    for (var k = 0u; k < P.n_sources; k++) {
        let src = P.sources[k];
        let dx = wrap_delta(x - src.x, P.size_x, (P.periodic & 1u) != 0u);
        let dz = wrap_delta(z - src.y, P.size_z, (P.periodic & 4u) != 0u);
        let t = clamp((src.z - sqrt(dx * dx + dz * dz)) / (0.3 * src.z), 0.0, 1.0);
        rate += src.w * t * t * (3.0 - 2.0 * t);
    }
    return rate;
}

// Environment temperature T0(y): piecewise linear with an optional capping inversion
// (EnvironmentConfig::temperature).
fn environment_temperature(y: f32) -> f32 {
    let below = min(y, P.inversion_base);
    let inside = clamp(y - P.inversion_base, 0.0, P.inversion_depth);
    let above = max(y - P.inversion_base - P.inversion_depth, 0.0);
    var rise = select(0.0, P.inversion_strength, y > P.inversion_base);
    if (P.inversion_depth > 0.0) { rise = P.inversion_strength * inside / P.inversion_depth; }
    return P.ground_temperature - P.lapse_rate * below + rise - P.lapse_above * above;
}

// The horizontal mean of eq. 6's force at height y, linear between layer centres
// (sim::thermo::layer_weights); 0 without a profile.
fn layer_mean(y: f32) -> f32 {
    if (P.n_layers == 0u) { return 0.0; }
    let t = clamp(y / P.layer_height - 0.5, 0.0, f32(P.n_layers - 1u));
    let k0 = u32(floor(t));
    let k1 = min(k0 + 1u, P.n_layers - 1u);
    let a = P.layers[k0 / 4u][k0 % 4u];
    let b = P.layers[k1 / 4u][k1 % 4u];
    return mix(a, b, t - f32(k0));
}

@compute @workgroup_size(WG_PARTICLES)
fn thermo_step(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= live.count) { return; }
    let p = pos[i].xyz;
    var u = vel[i];
    let th = thermo[i];
    var temp = th.x;
    var v = th.y;

    // eq. 5: dT/dt = Se near the ground, in a noise pattern over the ground that drifts in time;
    // a moist ground also evaporates Se / (Bowen ratio Q) of vapor (not in the paper).
    if (p.y < P.heat_height) {
        let heat = P.dt * heating_rate(p.x, p.z, P.time);
        temp = temp + heat;
        v = v + heat * P.ground_vapor;
    }

    // eq. 6: F = kb (T - T0) / T0 j - kg w j, applied as a velocity change dt F, less its
    // horizontal mean at this height when there is a profile (a force of height alone only
    // changes the pressure of a closed incompressible box).
    let t0 = environment_temperature(p.y);
    let force = P.buoyancy * (temp - t0) / t0 - P.cloud_weight * th.z;
    u.y = u.y + P.dt * (force - layer_mean(p.y));

    // eq. 7: dT = -Gamma_d dy over the height this substep's move gained (vel.w, written by
    // pbf.wgsl's update_velocity): T + Gamma_d y is kept exactly by a dry parcel, however the
    // constraint solve moved it (u_y dt cooled parcels that the solve held in place).
    temp = temp - P.adiabatic_lapse_rate * u.w;

    // eqs. 8-10: w moves towards v - gamma, gamma = min(A exp(B / (T + C)), v + w). The total
    // s = v + w is kept: w is clamped into [0, s] and v = s - w, so neither goes negative.
    let w = th.z;
    let s = v + w;
    let gamma = min(P.saturation_a * exp(P.saturation_b / max(temp + P.saturation_c, 1e-3)), s);
    let w_new = clamp(w + P.phase_fraction * (v - gamma), 0.0, s);
    let v_new = s - w_new;

    // eq. 11: latent heat Q per unit of condensed water (negative when evaporating).
    temp = temp + P.latent_heat * (w_new - w);

    vel[i] = u;
    thermo[i] = vec4<f32>(temp, v_new, w_new, th.w);
}
