//! The heating and vapour sources as a field over space, in f64: the noise pattern near the
//! ground, every configured source and the target-shape control's maps. The host's heat budget
//! (`diagnostics`) evaluates it; it is also the f64 mirror of thermo.wgsl's `source_rates` and
//! its helpers, re-exported by `reference::thermo` under the shaders' names.
use crate::ground::noise::value_noise3;
use crate::sim::sources::{
    SourceGpu, KIND_AIR_BOX, KIND_DISC, KIND_ELLIPSE, KIND_GROUND_BOX, KIND_IMAGE, KIND_SPHERE,
};
use crate::sim::thermo::ThermoParams;

/// Heat source fraction in [0, 1] at ground point (x, z) and time t (mirror of `heat_factor`).
pub fn heat_factor(p: &ThermoParams, x: f64, z: f64, time: f64) -> f64 {
    let n = value_noise3(
        x,
        z,
        time * p.noise_speed as f64,
        p.noise_cell_x as f64,
        p.noise_cell_z as f64,
        p.noise_period_x,
        p.noise_period_z,
        p.seed,
    );
    ((n - 0.5) * p.noise_contrast as f64 + 0.5).clamp(0.0, 1.0)
}

/// Shortest signed distance along an axis of extent `s`, wrapped when periodic.
fn wrap_delta(d: f64, s: f64, periodic: bool) -> f64 {
    if periodic {
        d - s * (d / s).round()
    } else {
        d
    }
}

/// Smoothstep from 0 at q = 1 to 1 at q = 0.7 and inside (mirror of `edge`).
fn edge(q: f64) -> f64 {
    let t = ((1.0 - q) / 0.3).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Pixel index of a map n wide: wrapped or clamped (mirror of `map_pixel`).
fn map_pixel(i: i64, n: u32, periodic: bool) -> usize {
    if periodic {
        i.rem_euclid(n as i64) as usize
    } else {
        i.clamp(0, n as i64 - 1) as usize
    }
}

/// A heat map at ground point (x, z), bilinear between pixel centres (mirror of `heat_map`);
/// `e` = (kind, offset, width, height), `maps` the stage's map values.
pub fn heat_map(p: &ThermoParams, maps: &[f32], e: [u32; 4], x: f64, z: f64) -> f64 {
    if e[2] == 0 {
        return 0.0;
    }
    let (px, pz) = (p.periodic & 1 != 0, p.periodic & 4 != 0);
    let u = x / p.size_x as f64 * e[2] as f64 - 0.5;
    let w = z / p.size_z as f64 * e[3] as f64 - 0.5;
    let (fu, fw) = (u.floor(), w.floor());
    let i0 = map_pixel(fu as i64, e[2], px);
    let i1 = map_pixel(fu as i64 + 1, e[2], px);
    let r0 = e[1] as usize + map_pixel(fw as i64, e[3], pz) * e[2] as usize;
    let r1 = e[1] as usize + map_pixel(fw as i64 + 1, e[3], pz) * e[2] as usize;
    let m = |k: usize| maps[k] as f64;
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let a = lerp(m(r0 + i0), m(r0 + i1), u - fu);
    let b = lerp(m(r1 + i0), m(r1 + i1), u - fu);
    lerp(a, b, w - fw)
}

/// Strength fraction of a source other than a disc at `pos`, with the wrapped offsets (dx, dz)
/// from its centre (mirror of `shape_factor`).
pub fn shape_factor(
    p: &ThermoParams,
    maps: &[f32],
    s: &SourceGpu,
    pos: [f64; 3],
    dx: f64,
    dz: f64,
) -> f64 {
    let (c, sn) = (s.rate[0] as f64, s.rate[1] as f64);
    let e = s.extent.map(|v| v as f64);
    let lx = c * dx + sn * dz;
    let lz = c * dz - sn * dx;
    let dy = pos[1] - s.center[1] as f64;
    match s.kind[0] {
        KIND_ELLIPSE => edge(((lx / e[0]).powi(2) + (lz / e[1]).powi(2)).sqrt()),
        KIND_GROUND_BOX => edge(lx.abs() / e[0]) * edge(lz.abs() / e[1]),
        KIND_SPHERE => edge((dx * dx + dy * dy + dz * dz).sqrt() / e[0]),
        KIND_AIR_BOX => edge(lx.abs() / e[0]) * edge(dy.abs() / e[1]) * edge(lz.abs() / e[2]),
        KIND_IMAGE => heat_map(p, maps, s.kind, pos[0], pos[2]),
        _ => 0.0,
    }
}

/// (heating K/s, vapor kg/kg/s) at a position at the time in `p`: the noise pattern below
/// `heat_height` and every source (mirror of `source_rates`); `maps`: the heat-map values
/// the stage holds ([`crate::sim::thermo::HeatMaps`]).
pub fn source_rates(p: &ThermoParams, maps: &[f32], pos: [f64; 3]) -> [f64; 2] {
    let mut rate = 0.0;
    let mut vapor = 0.0;
    if p.heat_noise != 0 && pos[1] < p.heat_height as f64 {
        rate = p.heat_source as f64 * heat_factor(p, pos[0], pos[2], p.time as f64);
    }
    for s in &p.sources[..p.n_sources as usize] {
        if pos[1] >= s.center[3] as f64 {
            continue;
        }
        let dx = wrap_delta(
            pos[0] - s.center[0] as f64,
            p.size_x as f64,
            p.periodic & 1 != 0,
        );
        let dz = wrap_delta(
            pos[2] - s.center[2] as f64,
            p.size_z as f64,
            p.periodic & 4 != 0,
        );
        let f = if s.kind[0] == KIND_DISC {
            crate::config::HeatSource::falloff(s.extent[0] as f64, dx, dz)
        } else {
            shape_factor(p, maps, s, pos, dx, dz)
        };
        rate += s.rate[2] as f64 * f;
        vapor += s.rate[3] as f64 * f;
    }
    if p.control[0] != 0 {
        let [_, offset, nx, nz] = p.control;
        let mask = heat_map(
            p,
            maps,
            [KIND_IMAGE, offset + nx * nz, nx, nz],
            pos[0],
            pos[2],
        );
        rate *= mask;
        vapor *= mask;
        if pos[1] < p.control_rate[2] as f64 {
            let f = heat_map(p, maps, [KIND_IMAGE, offset, nx, nz], pos[0], pos[2]);
            rate += f * p.control_rate[0] as f64;
            vapor += f * p.control_rate[1] as f64;
        }
    }
    [rate, vapor]
}
