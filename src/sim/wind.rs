//! `physics.wind` for the thermo stage: the profile as rows (height m, speed m/s, heading rad)
//! and the relaxation fraction of a substep.
//!
//! Each substep of dt moves a particle's horizontal velocity u_h the fraction
//! f = 1 - exp(-dt / tau) of the way to the profile's U(y): the exact solution of
//! du_h/dt = (U(y) - u_h) / tau over dt with U held, so any number of substeps relaxes the same
//! (as eq. 9's phase transition). The headings are unwrapped along the profile (each differs
//! from the one below by at most 180 degrees), so the direction turns the short way between
//! two levels. The momentum this adds in a substep is sum_i m_i f (U(y_i) - u_h,i): the nudging
//! term; nothing else changes the total (docs/PHYSICS.md "Wind"). With `coriolis` the profile is
//! a geostrophic wind, which `sim::forces::coriolis` turns the air about instead.
use crate::config::{ShotConfig, WindLevel};

/// Most levels of `physics.wind.profile`.
pub const MAX_WIND_LEVELS: usize = crate::config::MAX_WIND_LEVELS;

/// (levels in use, rows) of a shot's wind; (0, zeros) without wind.
pub fn rows(cfg: &ShotConfig) -> (u32, [[f32; 4]; MAX_WIND_LEVELS]) {
    match &cfg.physics.wind {
        Some(w) => rows_of(&w.profile),
        None => (0, [[0.0f32; 4]; MAX_WIND_LEVELS]),
    }
}

/// (levels in use, rows) of a list of wind levels.
pub fn rows_of(levels: &[WindLevel]) -> (u32, [[f32; 4]; MAX_WIND_LEVELS]) {
    let mut out = [[0.0f32; 4]; MAX_WIND_LEVELS];
    let mut heading = 0.0f64;
    let mut prev: Option<f64> = None;
    for (row, l) in out.iter_mut().zip(levels) {
        let a = l.direction.to_radians();
        heading = match prev {
            None => a,
            // the turn from the level below, taken the short way
            Some(p) => {
                let d: f64 = a - p;
                heading + (d - std::f64::consts::TAU * (d / std::f64::consts::TAU).round())
            }
        };
        prev = Some(a);
        *row = [l.height as f32, l.speed as f32, heading as f32, 0.0];
    }
    (levels.len().min(MAX_WIND_LEVELS) as u32, out)
}

/// The wind particles start with at height y (`physics.wind.initial`); `None` without one.
pub fn initial_at(cfg: &ShotConfig, y: f64) -> Option<[f64; 2]> {
    let w = cfg
        .physics
        .wind
        .as_ref()
        .filter(|w| !w.initial.is_empty())?;
    let (n, rows) = rows_of(&w.initial);
    Some(profile_wind(&rows[..n as usize], y))
}

/// 1 - exp(-dt / tau) of a substep of `dt` (s); 0 without wind.
pub fn fraction(cfg: &ShotConfig, dt: f64) -> f32 {
    cfg.physics
        .wind
        .as_ref()
        .map_or(0.0, |w| -(-dt / w.time_constant).exp_m1()) as f32
}

/// (levels, rows) of the wind the thermo stage relaxes towards: the shot's, or none when the
/// profile is a geostrophic wind (`physics.wind.coriolis`: `sim::forces::coriolis` acts).
pub fn relaxed_rows(cfg: &ShotConfig) -> (u32, [[f32; 4]; MAX_WIND_LEVELS]) {
    match cfg
        .physics
        .wind
        .as_ref()
        .is_some_and(|w| w.coriolis.is_some())
    {
        true => (0, [[0.0; 4]; MAX_WIND_LEVELS]),
        false => rows(cfg),
    }
}

/// The wind (u_x, u_z) at height y of a table of (height, speed, heading, -) rows by increasing
/// height (`sim::wind::rows`): linear between rows, constant outside; (0, 0) without rows.
pub fn profile_wind(rows: &[[f32; 4]], y: f64) -> [f64; 2] {
    if rows.is_empty() {
        return [0.0; 2];
    }
    let row = |k: usize| rows[k].map(|v| v as f64);
    let (mut a, mut b) = (row(0), row(0));
    for k in 1..rows.len() {
        b = row(k);
        if y < b[0] {
            break;
        }
        a = b;
    }
    let t = if b[0] > a[0] {
        ((y - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let speed = a[1] + (b[1] - a[1]) * t;
    let heading = a[2] + (b[2] - a[2]) * t;
    [speed * heading.cos(), speed * heading.sin()]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shot(wind: &str) -> ShotConfig {
        crate::shot::load_str(
            &format!(
                "shot: t\noutput: {{frames: {{start: 1, end: 2}}}}\n\
                 domain: {{size: [400, 400, 400], spacing: 50}}\nphysics: {{wind: {wind}}}\n"
            ),
            "t.yaml",
            &[],
        )
        .unwrap()
        .into_config()
    }

    #[test]
    fn headings_turn_the_short_way() {
        let cfg = shot(
            "{profile: [{height: 0, speed: 2, direction: 350}, {height: 500, speed: 5, direction: 10}, \
             {height: 900, speed: 5, direction: -170}]}",
        );
        let (n, r) = rows(&cfg);
        assert_eq!(n, 3);
        let deg = |x: f32| (x as f64).to_degrees();
        assert!((deg(r[0][2]) - 350.0).abs() < 1e-4);
        // 350 -> 10 is a turn of +20, not -340
        assert!((deg(r[1][2]) - 370.0).abs() < 1e-4, "{}", deg(r[1][2]));
        // 10 -> -170 is 180 either way; the rounding takes one of them
        assert!(((deg(r[2][2]) - deg(r[1][2])).abs() - 180.0).abs() < 1e-3);
        assert_eq!([r[1][0], r[1][1]], [500.0, 5.0]);
    }

    #[test]
    fn particles_start_with_the_initial_wind() {
        let cfg = shot(
            "{profile: [{height: 0, speed: 1}], initial: [{height: 0, speed: 2, direction: 180}, \
             {height: 1000, speed: 4, direction: 180}]}",
        );
        let u = initial_at(&cfg, 500.0).unwrap();
        assert!((u[0] + 3.0).abs() < 1e-6 && u[1].abs() < 1e-6, "{u:?}");
        let u = initial_at(&cfg, 2000.0).unwrap();
        assert!((u[0] + 4.0).abs() < 1e-6, "{u:?}");
        assert_eq!(
            initial_at(&shot("{profile: [{height: 0, speed: 1}]}"), 5.0),
            None
        );
        // the particles: the random speeds (0 here) plus the wind at their height
        let mut c = cfg.clone();
        c.physics.initial_speed = 0.0;
        let s = crate::sim::init::initial_particles(&c);
        for (p, v) in s.pos.iter().zip(&s.vel) {
            let want = -(2.0 + 2.0 * (p[1] as f64 / 1000.0).min(1.0));
            assert!(
                (v[0] as f64 - want).abs() < 1e-5 && v[2].abs() < 1e-5,
                "{p:?} {v:?}"
            );
        }
    }

    #[test]
    fn fraction_is_exact_over_any_substeps() {
        let cfg = shot("{time_constant: 30, profile: [{height: 0, speed: 1}]}");
        let one = fraction(&cfg, 8.0) as f64;
        let four = 1.0 - (1.0 - fraction(&cfg, 2.0) as f64).powi(4);
        assert!((one - (1.0 - (-8.0f64 / 30.0).exp())).abs() < 1e-7);
        assert!((one - four).abs() < 1e-6, "{one} vs {four}");
        assert_eq!(fraction(&shot("null"), 8.0), 0.0);
    }
}
