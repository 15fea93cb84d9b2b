// Cloud thermodynamics of one substep, per particle (paper section 4, in the paper's order
// after the PBF move and the temperature smoothing):
//   ground heating and sources (eq. 5, and the ground's evaporation) -> buoyancy and cloud
//   weight (eq. 6), wind -> adiabatic cooling (eq. 7)
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
    layer_height: f32,
    // vapor per kelvin of ground heating, 1 / (Bowen ratio Q) (0 = dry ground)
    ground_vapor: f32,
    // levels of the wind profile (0 = no wind) and 1 - exp(-dt / tau) (physics.wind)
    n_wind: u32,
    wind_fraction: f32,
    // physics.thermodynamics: atmospheric (1) multiplies eq. 10's saturation by
    // p0 / p(y) = pressure_surface (1 - y / pressure_top)^(-pressure_exponent)
    atmospheric: u32,
    pressure_top: f32,
    pressure_exponent: f32,
    pressure_surface: f32,
    // levels of physics.environment.profile (0: the lapse rates and the inversion) and their
    // (height m, T0 K, -, -) by increasing height
    n_env: u32,
    // 0.608 with physics.virtual_temperature, else 0 (T (1 + 0 v) is T exactly)
    virtual_factor: f32,
    _env_pad1: u32,
    _env_pad2: u32,
    env: array<vec4<f32>, MAX_ENVIRONMENT_LEVELS>,
    // the profile (m/s^2) at the layer centres, four a row (sim::thermo::LayerBuoyancy)
    layers: array<vec4<f32>, MAX_LAYERS / 4u>,
    // --- art direction (sim::wind, sim::sources) ---
    // (height m, speed m/s, heading rad unwrapped along the profile, -) by increasing height
    wind: array<vec4<f32>, MAX_WIND_LEVELS>,
    sources: array<Source, MAX_SOURCES>,
    // --- target-shape control (sim::control) ---
    // (1 when on, offset of the supply map in heat_maps, columns along x, along z); the
    // footprint mask follows the supply map
    control: vec4<u32>,
    // (heating K/s, vapor kg/kg/s at a supply factor of 1, top of the supplied layer m,
    // voxels along y)
    control_rate: vec4<f32>,
    // (pull m/s^2, reach m, cloud threshold kg/kg, voxel height m); the pull field follows the
    // mask, four values per voxel (x fastest, then z, then y)
    control_pull: vec4<f32>,
}

// Mirror of sim::sources::SourceGpu.
struct Source {
    // (kind, heat-map offset, width, height); kinds: 0 disc, 1 ellipse, 2 box on the ground,
    // 3 sphere, 4 box in the air, 5 image
    kind: vec4<u32>,
    // (x, y, z, top of the heated layer; 3e38 in the air)
    center: vec4<f32>,
    // radius, semi-axes or half edges (m)
    extent: vec4<f32>,
    // (cos angle, sin angle, heating K/s, vapor kg/kg/s) at this substep
    rate: vec4<f32>,
}

@group(0) @binding(0) var<uniform> P: ThermoParams;
@group(0) @binding(1) var<storage, read> pos: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> vel: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> thermo: array<vec4<f32>>;
// every image source's heat map, row-major (row = z), at its source's offset
@group(0) @binding(4) var<storage, read> heat_maps: array<f32>;
@group(0) @binding(5) var<storage, read> live: Live;

// Lattice value in [0, 1): the top 24 bits are exact in f32, so GPU and mirror agree.
fn lattice_value(ix: i32, iz: i32, it: i32, seed: u32) -> f32 {
    let h = pcg_hash(bitcast<u32>(ix) ^ pcg_hash(bitcast<u32>(iz) ^ pcg_hash(bitcast<u32>(it) ^ pcg_hash(seed))));
    return f32(h >> 8u) * (1.0 / 16777216.0);
}

fn fade(u: f32) -> f32 {
    return u * u * u * (u * (u * 6.0 - 15.0) + 10.0);
}

fn wrap_index(i: i32, period: u32) -> i32 {
    let p = max(period, 1u);
    // no `%` of a negative operand: GLSL leaves its sign undefined (on llvmpipe's OpenGL it
    // broke the heat maps' wrap at x < half a pixel)
    if (i >= 0) { return i32(u32(i) % p); }
    return i32(p - 1u - u32(-(i + 1)) % p);
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

// Smoothstep from 0 at q = 1 (the shape's edge) to 1 at q = 0.7 and inside.
fn edge(q: f32) -> f32 {
    let t = clamp((1.0 - q) / 0.3, 0.0, 1.0);
    return t * t * (3.0 - 2.0 * t);
}

// Pixel index i of a map n wide: wrapped on a periodic axis, clamped on a walled one.
fn map_pixel(i: i32, n: u32, periodic: bool) -> u32 {
    if (periodic) { return u32(wrap_index(i, n)); }
    return u32(clamp(i, 0, i32(n) - 1));
}

// A heat map over the ground at (x, z): bilinear between pixel centres.
fn heat_map(e: vec4<u32>, x: f32, z: f32) -> f32 {
    if (e.z == 0u) { return 0.0; }
    let px = (P.periodic & 1u) != 0u;
    let pz = (P.periodic & 4u) != 0u;
    let u = x / P.size_x * f32(e.z) - 0.5;
    let w = z / P.size_z * f32(e.w) - 0.5;
    let fu = floor(u);
    let fw = floor(w);
    let i0 = map_pixel(i32(fu), e.z, px);
    let i1 = map_pixel(i32(fu) + 1, e.z, px);
    let r0 = e.y + map_pixel(i32(fw), e.w, pz) * e.z;
    let r1 = e.y + map_pixel(i32(fw) + 1, e.w, pz) * e.z;
    let a = mix(heat_maps[r0 + i0], heat_maps[r0 + i1], u - fu);
    let b = mix(heat_maps[r1 + i0], heat_maps[r1 + i1], u - fu);
    return mix(a, b, w - fw);
}

// Strength fraction in [0, 1] of a source other than a disc at p, with the wrapped offsets
// (dx, dz) from its centre (mirror: sim::reference::thermo::shape_factor).
fn shape_factor(s: Source, p: vec3<f32>, dx: f32, dz: f32) -> f32 {
    // in the frame of a shape turned by its angle about y
    let lx = s.rate.x * dx + s.rate.y * dz;
    let lz = s.rate.x * dz - s.rate.y * dx;
    let dy = p.y - s.center.y;
    switch s.kind.x {
        case 1u: { return edge(sqrt((lx / s.extent.x) * (lx / s.extent.x) + (lz / s.extent.y) * (lz / s.extent.y))); }
        case 2u: { return edge(abs(lx) / s.extent.x) * edge(abs(lz) / s.extent.y); }
        case 3u: { return edge(sqrt(dx * dx + dy * dy + dz * dz) / s.extent.x); }
        case 4u: { return edge(abs(lx) / s.extent.x) * edge(abs(dy) / s.extent.y) * edge(abs(lz) / s.extent.z); }
        case 5u: { return heat_map(s.kind, p.x, p.z); }
        default: { return 0.0; }
    }
}

// (heating K/s, vapor kg/kg/s) at p: the noise pattern below heat_height and every source
// (mirror: sim::reference::thermo::source_rates).
fn source_rates(p: vec3<f32>, time: f32) -> vec2<f32> {
    var rate = 0.0;
    var vapor = 0.0;
    if (P.heat_noise != 0u && p.y < P.heat_height) { rate = P.heat_source * heat_factor(p.x, p.z, time); }
    for (var k = 0u; k < P.n_sources; k++) {
        let s = P.sources[k];
        // a ground shape acts below the top of its layer
        if (p.y >= s.center.w) { continue; }
        let dx = wrap_delta(p.x - s.center.x, P.size_x, (P.periodic & 1u) != 0u);
        let dz = wrap_delta(p.z - s.center.z, P.size_z, (P.periodic & 4u) != 0u);
        if (s.kind.x == 0u) {
            // the disc as before the other shapes existed, so its shots stay bit-identical
            let t = clamp((s.extent.x - sqrt(dx * dx + dz * dz)) / (0.3 * s.extent.x), 0.0, 1.0);
            rate += s.rate.z * t * t * (3.0 - 2.0 * t);
            vapor += s.rate.w * t * t * (3.0 - 2.0 * t);
        } else {
            let f = shape_factor(s, p, dx, dz);
            rate += s.rate.z * f;
            vapor += s.rate.w * f;
        }
    }
    // target-shape control: the heating above times the footprint mask, plus the column's
    // supply below the supplied layer's top (both maps bilinear between column centres)
    if (P.control.x != 0u) {
        let n = P.control.z * P.control.w;
        let mask = heat_map(vec4<u32>(5u, P.control.y + n, P.control.z, P.control.w), p.x, p.z);
        rate *= mask;
        vapor *= mask;
        if (p.y < P.control_rate.z) {
            let f = heat_map(vec4<u32>(5u, P.control.y, P.control.z, P.control.w), p.x, p.z);
            rate += f * P.control_rate.x;
            vapor += f * P.control_rate.y;
        }
    }
    return vec2<f32>(rate, vapor);
}

// The pull of the target-shape control on a particle with cloud water w at p (m/s^2): towards
// the nearest target voxel, from the voxel holding p, within the reach (mirror:
// sim::reference::thermo::target_pull).
fn target_pull(p: vec3<f32>, w: f32) -> vec3<f32> {
    if (P.control.x == 0u || P.control_pull.x <= 0.0 || w <= P.control_pull.z) { return vec3<f32>(0.0); }
    let nx = P.control.z;
    let nz = P.control.w;
    let ny = u32(P.control_rate.w);
    let i = min(u32(max(floor(p.x / (P.size_x / f32(nx))), 0.0)), nx - 1u);
    let j = min(u32(max(floor(p.y / P.control_pull.w), 0.0)), ny - 1u);
    let k = min(u32(max(floor(p.z / (P.size_z / f32(nz))), 0.0)), nz - 1u);
    let at = P.control.y + 2u * nx * nz + 4u * ((j * nz + k) * nx + i);
    let d = heat_maps[at + 3u];
    if (d <= 0.0 || d > P.control_pull.y) { return vec3<f32>(0.0); }
    return P.control_pull.x / d * vec3<f32>(heat_maps[at], heat_maps[at + 1u], heat_maps[at + 2u]);
}

// The wind (u_x, u_z) at height y: speed and heading linear between levels, constant
// outside them (mirror: sim::reference::thermo::wind_at).
fn wind_at(y: f32) -> vec2<f32> {
    var a = P.wind[0];
    var b = a;
    for (var k = 1u; k < P.n_wind; k++) {
        b = P.wind[k];
        if (y < b.x) { break; }
        a = b;
    }
    var t = 0.0;
    if (b.x > a.x) { t = clamp((y - a.x) / (b.x - a.x), 0.0, 1.0); }
    let speed = mix(a.y, b.y, t);
    let heading = mix(a.z, b.z, t);
    return speed * vec2<f32>(cos(heading), sin(heading));
}

// T0(y) of physics.environment.profile: linear between levels, constant outside them (mirror:
// sim::reference::thermo::profile_temperature).
fn profile_temperature(y: f32) -> f32 {
    let last = P.env[P.n_env - 1u];
    if (y <= P.env[0].x) { return P.env[0].y; }
    if (y >= last.x) { return last.y; }
    var k = 1u;
    while (k < P.n_env - 1u && P.env[k].x <= y) { k++; }
    let a = P.env[k - 1u];
    let b = P.env[k];
    return a.y + (y - a.x) / (b.x - a.x) * (b.y - a.y);
}

// Environment temperature T0(y): piecewise linear with an optional capping inversion
// (EnvironmentConfig::temperature).
fn environment_temperature(y: f32) -> f32 {
    if (P.n_env > 0u) { return profile_temperature(y); }
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

    // eq. 5: dT/dt = Se near the ground, in a noise pattern over the ground that drifts in time,
    // and the sources; a moist ground also evaporates Se / (Bowen ratio Q) of vapor, and vapor
    // sources add theirs (not in the paper). Where nothing heats, heat is 0 and T, v stay.
    let rates = source_rates(p, P.time);
    let heat = P.dt * rates.x;
    temp = temp + heat;
    v = v + heat * P.ground_vapor;
    v = v + P.dt * rates.y;

    // eq. 7: dT = -Gamma_d dy over the height this substep's move gained (vel.w, written by
    // pbf.wgsl's update_velocity): T + Gamma_d y is kept exactly by a dry parcel, however the
    // constraint solve moved it (u_y dt cooled parcels that the solve held in place). Before
    // eq. 6, which compares T with T0 at the particle's new height: with the T of the height it
    // left, a particle that rose by dy felt g Gamma_d dy / T0 of extra lift, a push along its
    // own motion of g Gamma_d dt / T0 per second (5e-3 / s at 15 s substeps) that grew waves
    // out of air at rest (docs/PHYSICS.md "BOMEX").
    temp = temp - P.adiabatic_lapse_rate * u.w;

    // eq. 6: F = kb (T - T0) / T0 j - kg w j, applied as a velocity change dt F, less its
    // horizontal mean at this height when there is a profile (a force of height alone only
    // changes the pressure of a closed incompressible box).
    // With physics.virtual_temperature, T is the virtual temperature T (1 + 0.608 v).
    let t0 = environment_temperature(p.y);
    let tv = temp * (1.0 + P.virtual_factor * v);
    let force = P.buoyancy * (tv - t0) / t0 - P.cloud_weight * th.z;
    u.y = u.y + P.dt * (force - layer_mean(p.y));

    // target-shape control (not in the paper): cloud near the target is pulled into it
    // (only where it acts, so a shot without control keeps every bit, signed zeros included)
    if (P.control.x != 0u) {
        let pull = target_pull(p, th.z);
        u = vec4<f32>(u.xyz + P.dt * pull, u.w);
    }

    // wind (not in the paper): the horizontal velocity relaxes towards the profile at this
    // height, exactly over dt (1 - exp(-dt / tau)), so the substeps do not change it.
    if (P.n_wind > 0u) {
        let air = wind_at(p.y);
        u.x = u.x + P.wind_fraction * (air.x - u.x);
        u.z = u.z + P.wind_fraction * (air.y - u.z);
    }

    // eqs. 8-10: w moves towards v - gamma, gamma = min(A exp(B / (T + C)), v + w). The total
    // s = v + w is kept: w is clamped into [0, s] and v = s - w, so neither goes negative.
    let w = th.z;
    let s = v + w;
    var saturation = P.saturation_a * exp(P.saturation_b / max(temp + P.saturation_c, 1e-3));
    if (P.atmospheric != 0u) {
        saturation = saturation * P.pressure_surface * pow(1.0 - p.y / P.pressure_top, -P.pressure_exponent);
    }
    let gamma = min(saturation, s);
    let w_new = clamp(w + P.phase_fraction * (v - gamma), 0.0, s);
    let v_new = s - w_new;

    // eq. 11: latent heat Q per unit of condensed water (negative when evaporating).
    temp = temp + P.latent_heat * (w_new - w);

    vel[i] = u;
    thermo[i] = vec4<f32>(temp, v_new, w_new, th.w);
}
