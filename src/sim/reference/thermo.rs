//! f64 mirror of shaders/thermo.wgsl (`thermo_step`): heating and sources, buoyancy, wind,
//! adiabatic cooling, phase transition and latent heat of one substep (eqs. 5-11). The constants come from the
//! same [`ThermoParams`] the GPU gets, widened to f64.
/// The sources' field: the host's own (`sim::source_field`), the same f64 code.
pub use crate::sim::source_field::{heat_factor, heat_map, shape_factor, source_rates};
use crate::sim::thermo::ThermoParams;

/// Saturation limit gamma of eq. 10 at height y: `min(A exp(B / (T + C)), v + w)`, the
/// saturation times p0 / p(y) with atmospheric thermodynamics.
pub fn saturation_limit(p: &ThermoParams, temperature: f64, y: f64, vapor: f64, cloud: f64) -> f64 {
    let mut sat = p.saturation_a as f64
        * (p.saturation_b as f64 / (temperature + p.saturation_c as f64).max(1e-3)).exp();
    if p.atmospheric != 0 {
        sat *= p.pressure_surface as f64
            * (1.0 - y / p.pressure_top as f64).powf(-(p.pressure_exponent as f64));
    }
    sat.min(vapor + cloud)
}

/// The pull of the target-shape control on a particle with cloud water `w` at `pos`
/// (m/s^2; mirror of `target_pull`).
pub fn target_pull(p: &ThermoParams, maps: &[f32], pos: [f64; 3], w: f64) -> [f64; 3] {
    let pull = p.control_pull.map(|v| v as f64);
    if p.control[0] == 0 || pull[0] <= 0.0 || w <= pull[2] {
        return [0.0; 3];
    }
    let [_, offset, nx, nz] = p.control.map(|v| v as usize);
    let ny = p.control_rate[3] as usize;
    let cell = |x: f64, c: f64, n: usize| ((x / c).floor().max(0.0) as usize).min(n - 1);
    let i = cell(pos[0], p.size_x as f64 / nx as f64, nx);
    let j = cell(pos[1], pull[3], ny);
    let k = cell(pos[2], p.size_z as f64 / nz as f64, nz);
    let at = offset + 2 * nx * nz + 4 * ((j * nz + k) * nx + i);
    let d = maps[at + 3] as f64;
    if d <= 0.0 || d > pull[1] {
        return [0.0; 3];
    }
    [0, 1, 2].map(|a| pull[0] / d * maps[at + a] as f64)
}

/// The wind (u_x, u_z) at height y (mirror of `wind_at`); (0, 0) without wind.
pub fn wind_at(p: &ThermoParams, y: f64) -> [f64; 2] {
    profile_wind(&p.wind[..p.n_wind as usize], y)
}

/// The table lookup of `wind_at`: the host's own (`sim::wind::profile_wind`), the same f64 code.
pub use crate::sim::wind::profile_wind;

/// T0(y) of the profile's levels: linear between them, constant outside (mirror of
/// `profile_temperature`).
pub fn profile_temperature(p: &ThermoParams, y: f64) -> f64 {
    let levels = &p.env[..p.n_env as usize];
    let (first, last) = (levels[0], levels[levels.len() - 1]);
    if y <= first[0] as f64 {
        return first[1] as f64;
    }
    if y >= last[0] as f64 {
        return last[1] as f64;
    }
    let k = levels.partition_point(|l| l[0] as f64 <= y);
    let (a, b) = (levels[k - 1].map(|v| v as f64), levels[k].map(|v| v as f64));
    a[1] + (y - a[0]) / (b[0] - a[0]) * (b[1] - a[1])
}

/// Environment temperature T0(y) of the parameters (mirror of `environment_temperature`).
pub fn environment_temperature(p: &ThermoParams, y: f64) -> f64 {
    if p.n_env > 0 {
        return profile_temperature(p, y);
    }
    let base = p.inversion_base as f64;
    let depth = p.inversion_depth as f64;
    let strength = p.inversion_strength as f64;
    let below = y.min(base);
    let inside = (y - base).clamp(0.0, depth);
    let above = (y - base - depth).max(0.0);
    let rise = if depth > 0.0 {
        strength * inside / depth
    } else if y > base {
        strength
    } else {
        0.0
    };
    p.ground_temperature as f64 - p.lapse_rate as f64 * below + rise - p.lapse_above as f64 * above
}

/// The horizontal-mean profile at height y (mirror of `layer_mean`); 0 without one.
pub fn layer_mean(p: &ThermoParams, y: f64) -> f64 {
    if p.n_layers == 0 {
        return 0.0;
    }
    let n = p.n_layers as usize;
    let (k0, k1, f) = crate::sim::thermo::layer_weights(y, p.layer_height as f64, n);
    let v = |k: usize| p.layers[k / 4][k % 4] as f64;
    v(k0) + f * (v(k1) - v(k0))
}

/// One particle: `pos` read, `vel` (xyz, w = the height gained by this substep's move) and
/// `thermo` = (T, v, w, E) updated in place; `maps`: the stage's heat-map values.
pub fn thermo_step_particle(
    p: &ThermoParams,
    maps: &[f32],
    pos: [f64; 3],
    vel: &mut [f64; 4],
    th: &mut [f64; 4],
) {
    let dt = p.dt as f64;
    let mut temp = th[0];
    // eq. 5 and the sources, and the ground's evaporation
    let [rate, vapor] = source_rates(p, maps, pos);
    let heat = dt * rate;
    temp += heat;
    th[1] += heat * p.ground_vapor as f64 + dt * vapor;
    // eq. 7, over the height gained by the move: before eq. 6, which reads T at pos
    temp -= p.adiabatic_lapse_rate as f64 * vel[3];
    // eq. 6
    let t0 = environment_temperature(p, pos[1]);
    let tv = temp * (1.0 + p.virtual_factor as f64 * th[1]);
    let force = p.buoyancy as f64 * (tv - t0) / t0 - p.cloud_weight as f64 * th[2];
    vel[1] += dt * (force - layer_mean(p, pos[1]));
    // wind: exact relaxation of the horizontal velocity over dt
    if p.n_wind > 0 {
        let f = p.wind_fraction as f64;
        let air = wind_at(p, pos[1]);
        vel[0] += f * (air[0] - vel[0]);
        vel[2] += f * (air[1] - vel[2]);
    }
    // target-shape control: the pull into the target
    if p.control[0] != 0 {
        let pull = target_pull(p, maps, pos, th[2]);
        for a in 0..3 {
            vel[a] += dt * pull[a];
        }
    }
    // eqs. 8-10
    let (v, w) = (th[1], th[2]);
    let s = v + w;
    let gamma = saturation_limit(p, temp, pos[1], v, w);
    let w_new = (w + p.phase_fraction as f64 * (v - gamma)).clamp(0.0, s);
    let v_new = s - w_new;
    // eq. 11
    temp += p.latent_heat as f64 * (w_new - w);
    *th = [temp, v_new, w_new, th[3]];
}

/// Mirror of the `thermo_step` entry: every particle of `pos` (the live ones).
pub fn thermo_step(
    p: &ThermoParams,
    maps: &[f32],
    pos: &[[f64; 3]],
    vel: &mut [[f64; 4]],
    thermo: &mut [[f64; 4]],
) {
    let n = pos.len();
    for ((q, u), th) in pos
        .iter()
        .zip(vel.iter_mut())
        .zip(thermo.iter_mut())
        .take(n)
    {
        thermo_step_particle(p, maps, *q, u, th);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ShotConfig;
    use crate::sim::thermo::{environment_temperature, initial_thermo, saturation};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn shot() -> ShotConfig {
        serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [4000.0, 3000.0, 4000.0], spacing: 40.0}\n",
        )
        .unwrap()
    }

    /// Random states, some far above and some far below saturation, stepped with every
    /// process on: v + w per particle is kept to f64 rounding, v and w never go negative,
    /// and the total water (no sources in the model) stays constant.
    #[test]
    fn phase_transition_conserves_water_per_particle() {
        let mut cfg = shot();
        cfg.physics.phase_rate = 2.0; // phase_fraction near 1: the hardest case for clamping
        let p = ThermoParams::new(&cfg, 2.0, 0.0);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let pos: Vec<[f64; 3]> = (0..500)
            .map(|_| {
                [
                    rng.random_range(0.0..4000.0),
                    rng.random_range(0.0..3000.0),
                    rng.random_range(0.0..4000.0),
                ]
            })
            .collect();
        let mut vel: Vec<[f64; 4]> = (0..500)
            .map(|_| {
                [
                    0.0,
                    rng.random_range(-5.0..5.0),
                    0.0,
                    rng.random_range(-5.0..5.0),
                ]
            })
            .collect();
        let mut th: Vec<[f64; 4]> = (0..500)
            .map(|_| {
                [
                    rng.random_range(250.0..310.0),
                    rng.random_range(0.0..0.03),
                    if rng.random_bool(0.5) {
                        rng.random_range(0.0..0.01)
                    } else {
                        0.0
                    },
                    0.0,
                ]
            })
            .collect();
        let total = |th: &[[f64; 4]]| th.iter().map(|t| t[1] + t[2]).sum::<f64>();
        let total0 = total(&th);
        let (mut condensed, mut evaporated) = (false, false);
        for step in 0..200 {
            let mut p = p;
            p.time = step as f32 * 2.0;
            let before = th.clone();
            thermo_step(&p, &[], &pos, &mut vel, &mut th);
            for (a, b) in before.iter().zip(&th) {
                let (s0, s1) = (a[1] + a[2], b[1] + b[2]);
                assert!(
                    (s1 - s0).abs() <= 4.0 * f64::EPSILON * s0.max(1e-300),
                    "{a:?} -> {b:?}"
                );
                assert!(b[1] >= 0.0 && b[2] >= 0.0, "{b:?}");
                condensed |= b[2] > a[2];
                evaporated |= b[2] < a[2];
            }
        }
        assert!(
            condensed && evaporated,
            "the test must exercise both directions"
        );
        let total1 = total(&th);
        assert!(
            (total1 - total0).abs() < 1e-12 * total0,
            "{total0} -> {total1}"
        );
    }

    /// Heating off, particles at rest in the environment with sub-saturated vapor (section 5
    /// initial state): nothing moves, warms or condenses.
    #[test]
    fn nothing_condenses_without_heating_when_subsaturated() {
        let mut cfg = shot();
        cfg.physics.heat_source = 0.0;
        let n = 300;
        let p = ThermoParams::new(&cfg, 2.0, 0.0);
        let pos: Vec<[f64; 3]> = (0..n)
            .map(|k| [13.0 * k as f64, 10.0 * k as f64, 7.0 * k as f64])
            .collect();
        let mut vel = vec![[0.0; 4]; n];
        // Exactly the environment (the f32 rounding of T0 would be a 1e-5 K excess).
        let mut th: Vec<[f64; 4]> = pos
            .iter()
            .map(|q| {
                let t0 = super::environment_temperature(&p, q[1]);
                let v = initial_thermo(&cfg.physics, q[1])[1] as f64;
                [t0, v, 0.0, 0.0]
            })
            .collect();
        let start = th.clone();
        for _ in 0..1000 {
            thermo_step(&p, &[], &pos, &mut vel, &mut th);
        }
        for (a, b) in start.iter().zip(&th) {
            assert_eq!(b[2], 0.0);
            assert_eq!(a[1], b[1]);
            assert!((a[0] - b[0]).abs() < 1e-9);
        }
        assert!(vel.iter().all(|v| v[1].abs() < 1e-12));
    }

    /// gamma of eq. 10 against an independent evaluation, including the min with v + w, and the
    /// default constants against the Magnus-Tetens saturation mixing ratio at 1000 hPa.
    #[test]
    fn saturation_limit_matches_eq10() {
        let cfg = shot();
        let p = ThermoParams::new(&cfg, 1.0, 0.0);
        let (a, b, c) = (
            p.saturation_a as f64,
            p.saturation_b as f64,
            p.saturation_c as f64,
        );
        for t in [250.0, 273.15, 285.0, 293.15, 305.0] {
            let sat = a * (b / (t + c)).exp();
            assert!((saturation(&cfg.physics, t, 0.0) - sat).abs() <= 1e-6 * sat);
            // Plenty of water: gamma is the saturation value.
            assert!((saturation_limit(&p, t, 0.0, 0.05, 0.02) - sat).abs() <= 1e-12 * sat);
            // Little water: gamma is v + w.
            assert_eq!(saturation_limit(&p, t, 0.0, 1e-4, 2e-4), 1e-4 + 2e-4);
            let magnus = 380.0 / 1.0e5 * (17.67 * (t - 273.15) / (t - 29.65)).exp();
            assert!(
                (sat - magnus).abs() < 2e-3 * magnus,
                "T {t}: {sat} vs {magnus}"
            );
        }
        let s20 = saturation(&cfg.physics, 293.15, 0.0);
        assert!((s20 - 0.0145).abs() < 0.0002, "{s20}");
    }

    /// With atmospheric thermodynamics the saturation goes as 1 / p(y): p(y) is the standard
    /// atmosphere's within 1% up to 3 km (the dry adiabat over 288 K is colder than 6.5 K/km:
    /// 695.4 hPa at 3 km against the U.S. Standard Atmosphere's 701.2), and gamma of the
    /// mirror is the host's saturation at that height; `paper` is unchanged by height.
    #[test]
    fn atmospheric_saturation_goes_as_one_over_the_pressure() {
        let mut cfg = shot();
        cfg.physics.ground_temperature = 288.15;
        let paper = saturation(&cfg.physics, 280.0, 2000.0);
        assert_eq!(paper, saturation(&cfg.physics, 280.0, 0.0));
        cfg.physics.thermodynamics = crate::config::Thermodynamics::Atmospheric;
        cfg.physics.surface_pressure = Some(101_325.0);
        let q = crate::sim::thermo::Pressure::of(&cfg.physics).unwrap();
        for (y, standard) in [(0.0, 1013.25), (1000.0, 898.76), (3000.0, 701.21)] {
            let hpa = q.at(y) / 100.0;
            assert!(
                (hpa / standard - 1.0).abs() < 1e-2,
                "{y} m: {hpa} hPa vs {standard}"
            );
        }
        let p = ThermoParams::new(&cfg, 1.0, 0.0);
        for y in [0.0, 500.0, 1500.0, 2900.0] {
            let host = saturation(&cfg.physics, 285.0, y);
            let expect = paper_at(&cfg, 285.0) * 1.0e5 / q.at(y);
            assert!(
                (host / expect - 1.0).abs() < 1e-12,
                "{y}: {host} vs {expect}"
            );
            let mirror = saturation_limit(&p, 285.0, y, 1.0, 0.0);
            assert!(
                (mirror / host - 1.0).abs() < 1e-5,
                "{y}: {mirror} vs {host}"
            );
        }
    }

    /// `environment.profile` gives T0(y) (linear between levels, constant outside) and the
    /// initial vapor; the mirror reads the same T0 from the uniform.
    #[test]
    fn the_environment_profile_sets_t0_and_the_initial_vapor() {
        let mut cfg = shot();
        cfg.physics.environment.profile = serde_saphyr::from_str(
            "[{height: 0, temperature: 299.0, vapor: 0.017}, \
             {height: 520, temperature: 293.9, vapor: 0.0163}, \
             {height: 1480, temperature: 288.2, vapor: 0.0107}]",
        )
        .unwrap();
        let p = ThermoParams::new(&cfg, 1.0, 0.0);
        for (y, t) in [
            (0.0, 299.0),
            (260.0, 296.45),
            (1000.0, 291.05),
            (2000.0, 288.2),
        ] {
            let host = environment_temperature(&cfg.physics, y);
            assert!((host - t).abs() < 1e-9, "{y}: {host} vs {t}");
            assert!(
                (super::environment_temperature(&p, y) - t).abs() < 1e-4,
                "{y}"
            );
        }
        let th = initial_thermo(&cfg.physics, 260.0);
        assert!((th[1] as f64 - 0.01665).abs() < 1e-7, "{th:?}");
        cfg.physics.environment.profile[1].vapor = None;
        let kv = initial_thermo(&cfg.physics, 260.0)[1] as f64;
        let sat = saturation(&cfg.physics, 296.45, 260.0);
        assert!((kv - cfg.physics.initial_vapor * sat).abs() < 1e-7, "{kv}");
    }

    fn paper_at(cfg: &crate::config::ShotConfig, t: f64) -> f64 {
        let p = &cfg.physics;
        p.saturation_a * (p.saturation_b / (t + p.saturation_c)).exp()
    }

    /// One parcel (a single particle, no neighbours, moved by its own velocity): heated near the
    /// ground it rises, cools at the dry lapse rate Gamma_d while w = 0, then saturates and from
    /// there cools more slowly (latent heat): the kink of the T(y) curve.
    #[test]
    fn heated_parcel_rises_dry_adiabatically_then_condenses() {
        // A drier start than the shot defaults, so the dry and the cloudy legs are both long.
        let mut cfg = shot();
        cfg.physics.initial_vapor = 0.5;
        cfg.physics.heat_source = 0.05;
        let (trace, base) = parcel_trace(&cfg, 2.0, 600);
        let gd = cfg.physics.adiabatic_lapse_rate;
        let Some(base) = base else {
            panic!("the parcel never saturated: {:?}", trace.last());
        };
        let first_dry = trace
            .iter()
            .position(|r| r.y > cfg.physics.heat_height)
            .expect("the parcel leaves the heated layer");
        assert!(
            base > first_dry + 5,
            "saturates too early: {base} vs {first_dry}"
        );
        // Dry part: T(y) follows -Gamma_d exactly (no heating above heat_height, no latent heat).
        let (r0, r1) = (&trace[first_dry], &trace[base - 1]);
        assert_eq!(r1.w, 0.0);
        let slope = (r1.t - r0.t) / (r1.y - r0.y);
        assert!((slope + gd).abs() < 1e-8, "dry slope {slope} vs {}", -gd);
        // Cloudy part: water condenses and the parcel cools less than Gamma_d with height.
        let end = trace.len() - 1;
        assert!(trace[end].w > 1e-4, "{:?}", trace[end]);
        let r2 = &trace[(base + end) / 2];
        let r3 = &trace[end];
        let moist = (r3.t - r2.t) / (r3.y - r2.y);
        assert!(r3.y > r2.y + 100.0, "the cloudy parcel keeps rising");
        assert!(
            moist > -0.8 * gd,
            "moist slope {moist} should be well above {}",
            -gd
        );
        println!("step   time      y        T      T0    v(g/kg) w(g/kg)");
        for (k, r) in trace.iter().enumerate().step_by(10) {
            println!(
                "{k:4} {:6.0} {:8.1} {:7.2} {:7.2} {:7.3} {:7.3}",
                r.time,
                r.y,
                r.t,
                r.t0,
                r.v * 1e3,
                r.w * 1e3
            );
        }
        println!("saturation at step {base}, y = {:.0} m", trace[base].y);
    }

    #[derive(Debug, Clone, Copy)]
    pub(crate) struct ParcelRow {
        pub time: f64,
        pub y: f64,
        pub t: f64,
        pub t0: f64,
        pub v: f64,
        pub w: f64,
    }

    /// A single particle starting in the heated layer at the hottest spot of the noise pattern,
    /// with the section 5 initial state; per step the move `y += u_y dt`, then `thermo_step`.
    /// Returns the trajectory and the first step with cloud (w > 0).
    pub(crate) fn parcel_trace(
        cfg: &ShotConfig,
        dt: f64,
        steps: usize,
    ) -> (Vec<ParcelRow>, Option<usize>) {
        let p0 = ThermoParams::new(cfg, dt, 0.0);
        // Hottest ground point of the pattern at t = 0 on a 20 m raster.
        let mut best = (0.0, 0.0, -1.0);
        for i in 0..(cfg.domain.size[0] / 20.0) as usize {
            for k in 0..(cfg.domain.size[2] / 20.0) as usize {
                let (x, z) = (i as f64 * 20.0, k as f64 * 20.0);
                let f = heat_factor(&p0, x, z, 0.0);
                if f > best.2 {
                    best = (x, z, f);
                }
            }
        }
        let y0 = 0.25 * cfg.physics.heat_height;
        let init = initial_thermo(&cfg.physics, y0);
        let mut th = [init[0] as f64, init[1] as f64, 0.0, 0.0];
        let mut pos = [best.0, y0, best.1];
        let mut vel = [0.0; 4];
        let mut trace = Vec::new();
        let mut base = None;
        for step in 0..steps {
            // the move, then the thermodynamics of the height it gained (the substep's order)
            pos[1] += vel[1] * dt;
            vel[3] = vel[1] * dt;
            let p = ThermoParams::new(cfg, dt, step as f64 * dt);
            thermo_step_particle(&p, &[], pos, &mut vel, &mut th);
            if th[2] > 0.0 && base.is_none() {
                base = Some(step);
            }
            trace.push(ParcelRow {
                time: (step + 1) as f64 * dt,
                y: pos[1],
                t: th[0],
                t0: environment_temperature(&cfg.physics, pos[1]),
                v: th[1],
                w: th[2],
            });
        }
        (trace, base)
    }
}
