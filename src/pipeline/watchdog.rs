//! The divergence watchdog: after every frame, before the frame is written or checkpointed, the
//! particle state read back for the writer is checked for non-finite values and for runaway
//! ones. A failed check stops the run with exit 3, "simulation diverged at frame N: ...",
//! naming the first bad field and particle; the frames before it and the last good checkpoint
//! stay, and the manifest stays `complete: false`.
use crate::config::ShotConfig;
use crate::ground::ParticleState;

/// Speeds are clamped to `solver.max_speed` once per substep; later corrections (XSPH,
/// position projection) move a particle a little past it, never this far.
pub const RUNAWAY_SPEED_FACTOR: f64 = 4.0;
/// Temperatures outside this range (K) are no cloud physics any more.
pub const TEMPERATURE_RANGE: (f64, f64) = (100.0, 1000.0);

/// The first problem of `state`, in words, or `None` when it is sane.
pub fn check(state: &ParticleState, cfg: &ShotConfig) -> Option<String> {
    let max_speed = RUNAWAY_SPEED_FACTOR * cfg.solver.max_speed;
    let (t_lo, t_hi) = TEMPERATURE_RANGE;
    for i in 0..state.len() {
        let who = || {
            let [id, level] = state.info.get(i).copied().unwrap_or([u32::MAX; 2]);
            format!("particle {i} (id {id}, level {level})")
        };
        let p = state.pos[i];
        if let Some(a) = (0..3).find(|&a| !p[a].is_finite()) {
            return Some(format!(
                "position.{} = {} at {}",
                "xyz".as_bytes()[a] as char,
                p[a],
                who()
            ));
        }
        let v = state.vel.get(i).copied().unwrap_or([f32::NAN; 4]);
        if let Some(a) = (0..3).find(|&a| !v[a].is_finite()) {
            return Some(format!(
                "velocity.{} = {} at {}",
                "xyz".as_bytes()[a] as char,
                v[a],
                who()
            ));
        }
        let speed = (0..3).map(|a| (v[a] as f64).powi(2)).sum::<f64>().sqrt();
        if speed > max_speed {
            return Some(format!(
                "speed {speed:.4e} m/s at {}, beyond {RUNAWAY_SPEED_FACTOR} x solver.max_speed ({} m/s)",
                who(),
                cfg.solver.max_speed
            ));
        }
        let th = state.thermo.get(i).copied().unwrap_or([f32::NAN; 4]);
        for (k, name) in ["temperature", "vapor", "cloud", "shape energy"]
            .iter()
            .enumerate()
        {
            if !th[k].is_finite() {
                return Some(format!("{name} = {} at {}", th[k], who()));
            }
        }
        let t = th[0] as f64;
        if !(t_lo..=t_hi).contains(&t) {
            return Some(format!(
                "temperature {t} K at {}, outside [{t_lo}, {t_hi}] K",
                who()
            ));
        }
        let rho = state.density.get(i).copied().unwrap_or(f32::NAN);
        if !rho.is_finite() {
            return Some(format!("density = {rho} at {}", who()));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(n: usize) -> ParticleState {
        ParticleState {
            pos: vec![[1.0, 2.0, 3.0, 0.0]; n],
            vel: vec![[1.0, 0.0, 0.0, 0.0]; n],
            thermo: vec![[290.0, 0.01, 0.0, 0.0]; n],
            info: (0..n as u32).map(|i| [i + 100, 0]).collect(),
            density: vec![1.0; n],
        }
    }

    fn cfg() -> ShotConfig {
        crate::shot::load_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
            "t.yaml",
            &[],
        )
        .unwrap().into_config()
    }

    #[test]
    fn names_the_first_bad_field_and_particle() {
        let c = cfg();
        assert_eq!(check(&state(3), &c), None);
        let mut s = state(3);
        s.thermo[1][0] = f32::NAN;
        let m = check(&s, &c).unwrap();
        assert!(m.contains("temperature = NaN at particle 1 (id 101"), "{m}");
        let mut s = state(3);
        s.thermo[2][0] = 1500.0;
        assert!(check(&s, &c).unwrap().contains("outside [100, 1000] K"));
        let mut s = state(3);
        s.vel[0][1] = 1e6;
        assert!(check(&s, &c).unwrap().starts_with("speed"));
        let mut s = state(3);
        s.pos[2][2] = f32::INFINITY;
        assert!(check(&s, &c).unwrap().starts_with("position.z = inf"));
    }
}
