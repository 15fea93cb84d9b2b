//! The preview's sky: a physical clear sky after Nishita et al. (1993), "Display of the Earth
//! taking into account atmospheric scattering" — the model behind Blender's Nishita sky texture,
//! which tools/render_blender.py lights and backs the cloud with — in three wavelengths (red,
//! green, blue), single scattering by air (Rayleigh) and aerosols (Mie, Henyey-Greenstein g =
//! 0.76), ozone absorption; seen from sea level. Below the horizon, as Cycles draws its Nishita
//! sky: the horizon's radiance at that azimuth fading to black ground, times (1 + 2.5 sin(el))^3
//! down to 23.6 degrees below (fitted to Blender's at 3 and 11 degrees below: 0.66 and 0.14 of
//! the horizon).
//!
//! The sun at the ground is the preview's own (`sun_color` x `sun_intensity`, the irradiance on
//! a plane facing it): the sun above the atmosphere is that divided by the model's transmittance
//! along the sun's path, so the sky follows the sun the shot sets. The radiances are tabulated
//! once (elevation x angle from the sun's azimuth) and read bilinearly.
//!
//! Against Blender 3.4.1's Nishita sky with render_blender.py's sun (40 degrees up): Blender's sky
//! adds (7.2, 9.0, 12.7) of irradiance on a level surface to the sun's (93.5, 76.0, 57.3) there,
//! this model (`tests::a_clear_sky_lights_a_level_surface_as_blenders_does`) within 25% in each
//! channel; the zenith is blue and the horizon whiter, as there.
use glam::DVec3;

const EARTH_RADIUS: f64 = 6360e3;
const ATMOSPHERE_RADIUS: f64 = 6420e3;
const RAYLEIGH_HEIGHT: f64 = 8000.0;
const MIE_HEIGHT: f64 = 1200.0;
/// Sea-level scattering coefficients (1/m) at 680, 550 and 440 nm (Bruneton & Neyret 2008).
const RAYLEIGH: [f64; 3] = [5.8e-6, 13.5e-6, 33.1e-6];
const MIE: f64 = 21e-6;
const MIE_EXTINCTION: f64 = MIE / 0.9;
const MIE_G: f64 = 0.76;
/// Ozone absorption at its peak (1/m), in a layer 15 km either side of 25 km.
const OZONE: [f64; 3] = [0.650e-6, 1.881e-6, 0.085e-6];
/// Table: elevations from the horizon up (non-uniform, dense at the horizon) x angles from the
/// sun's azimuth.
const ELEVATIONS: usize = 48;
const AZIMUTHS: usize = 33;

/// A clear sky for one sun.
#[derive(Debug, Clone)]
pub struct Sky {
    sun: DVec3,
    table: Vec<DVec3>,
    /// Mean radiance over the upper and the lower hemisphere (what a cloud's top and bottom
    /// see of the sky, in `ambient`).
    pub mean_up: DVec3,
    pub mean_down: DVec3,
}

impl Sky {
    /// The sky under a sun in direction `sun` (unit, y up) giving irradiance `sun_ground` at the
    /// ground.
    pub fn new(sun: DVec3, sun_ground: DVec3) -> Self {
        let sun = sun.normalize_or(DVec3::Y);
        // the sun above the atmosphere, from the one at the ground (a sun below the horizon
        // lights nothing)
        let t = transmittance(DVec3::new(0.0, EARTH_RADIUS + 1.0, 0.0), sun);
        let top = DVec3::from_array(std::array::from_fn(|c| {
            if t[c] > 1e-6 {
                sun_ground[c] / t[c]
            } else {
                0.0
            }
        }));
        let mut table = Vec::with_capacity(ELEVATIONS * AZIMUTHS);
        for i in 0..ELEVATIONS {
            let el = elevation_of_row(i);
            for j in 0..AZIMUTHS {
                let az = std::f64::consts::PI * j as f64 / (AZIMUTHS - 1) as f64;
                table.push(single_scattering(direction(sun, el, az), sun) * top);
            }
        }
        let mut sky = Self {
            sun,
            table,
            mean_up: DVec3::ZERO,
            mean_down: DVec3::ZERO,
        };
        let (up, down) = sky.hemisphere_means();
        sky.mean_up = up;
        sky.mean_down = down;
        sky
    }

    /// Radiance seen along unit direction `d`.
    pub fn radiance(&self, d: DVec3) -> DVec3 {
        if d.y < 0.0 {
            let fade = (1.0 + 2.5 * d.y).max(0.0).powi(3);
            return self.radiance(DVec3::new(d.x, 0.0, d.z)) * fade;
        }
        let el = d.y.clamp(-1.0, 1.0).asin();
        let flat = DVec3::new(d.x, 0.0, d.z);
        let sflat = DVec3::new(self.sun.x, 0.0, self.sun.z);
        let az = if flat.length_squared() > 1e-18 && sflat.length_squared() > 1e-18 {
            (flat.normalize().dot(sflat.normalize()))
                .clamp(-1.0, 1.0)
                .acos()
        } else {
            0.0
        };
        let r = row_of_elevation(el);
        let c = az / std::f64::consts::PI * (AZIMUTHS - 1) as f64;
        let (r0, c0) = (
            (r.floor() as usize).min(ELEVATIONS - 2),
            (c.floor() as usize).min(AZIMUTHS - 2),
        );
        let (fr, fc) = (r - r0 as f64, c - c0 as f64);
        let at = |i: usize, j: usize| self.table[i * AZIMUTHS + j];
        let top = at(r0, c0).lerp(at(r0, c0 + 1), fc);
        let bottom = at(r0 + 1, c0).lerp(at(r0 + 1, c0 + 1), fc);
        top.lerp(bottom, fr)
    }

    /// Irradiance of the sky (no sun) on a level surface facing up.
    pub fn level_irradiance(&self) -> DVec3 {
        let mut e = DVec3::ZERO;
        let n = 256;
        for i in 0..n {
            let el = (i as f64 + 0.5) / n as f64 * std::f64::consts::FRAC_PI_2;
            for j in 0..2 * n {
                let az = (j as f64 + 0.5) / (2 * n) as f64 * std::f64::consts::TAU;
                let d = DVec3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin());
                let dw = (std::f64::consts::FRAC_PI_2 / n as f64)
                    * (std::f64::consts::TAU / (2 * n) as f64)
                    * el.cos();
                e += self.radiance(d) * el.sin() * dw;
            }
        }
        e
    }

    fn hemisphere_means(&self) -> (DVec3, DVec3) {
        let (mut up, mut down) = (DVec3::ZERO, DVec3::ZERO);
        let (mut wu, mut wd) = (0.0, 0.0);
        let n = 48;
        for i in 0..2 * n {
            let el = -std::f64::consts::FRAC_PI_2
                + (i as f64 + 0.5) / (2 * n) as f64 * std::f64::consts::PI;
            for j in 0..2 * n {
                let az = (j as f64 + 0.5) / (2 * n) as f64 * std::f64::consts::TAU;
                let d = DVec3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin());
                let w = el.cos();
                if el > 0.0 {
                    up += self.radiance(d) * w;
                    wu += w;
                } else {
                    down += self.radiance(d) * w;
                    wd += w;
                }
            }
        }
        (up / wu, down / wd)
    }
}

/// Row i of the table (horizon to zenith): elevations spaced by the square of the row, so that
/// the rows are dense near the horizon, where the sky changes fastest.
fn elevation_of_row(i: usize) -> f64 {
    let u = i as f64 / (ELEVATIONS - 1) as f64;
    u * u * std::f64::consts::FRAC_PI_2
}

fn row_of_elevation(el: f64) -> f64 {
    (el.max(0.0) / std::f64::consts::FRAC_PI_2).sqrt() * (ELEVATIONS - 1) as f64
}

/// The direction at elevation `el` and angle `az` from the sun's azimuth.
fn direction(sun: DVec3, el: f64, az: f64) -> DVec3 {
    let s = DVec3::new(sun.x, 0.0, sun.z);
    let f = if s.length_squared() > 1e-18 {
        s.normalize()
    } else {
        DVec3::X
    };
    let side = DVec3::Y.cross(f);
    (f * az.cos() + side * az.sin()) * el.cos() + DVec3::Y * el.sin()
}

/// Extinction (1/m, per channel) at height h above the ground.
fn extinction(h: f64) -> DVec3 {
    let r = (-h / RAYLEIGH_HEIGHT).exp();
    let m = (-h / MIE_HEIGHT).exp();
    let o = (1.0 - (h - 25e3).abs() / 15e3).max(0.0);
    DVec3::from_array(std::array::from_fn(|c| {
        RAYLEIGH[c] * r + MIE_EXTINCTION * m + OZONE[c] * o
    }))
}

/// Distance from `p` along unit `d` to the sphere of radius `r` around the earth's centre
/// (the far intersection), `None` if the ray misses it.
fn to_sphere(p: DVec3, d: DVec3, r: f64) -> Option<(f64, f64)> {
    let b = p.dot(d);
    let c = p.length_squared() - r * r;
    let disc = b * b - c;
    (disc >= 0.0).then(|| {
        let s = disc.sqrt();
        (-b - s, -b + s)
    })
}

/// Transmittance from `p` (earth-centred, m) along `d` to the top of the atmosphere; 0 if the
/// earth is in the way.
fn transmittance(p: DVec3, d: DVec3) -> DVec3 {
    if let Some((t0, _)) = to_sphere(p, d, EARTH_RADIUS) {
        if t0 > 0.0 {
            return DVec3::ZERO;
        }
    }
    let Some((_, t1)) = to_sphere(p, d, ATMOSPHERE_RADIUS) else {
        return DVec3::ONE;
    };
    let n = 24;
    let ds = t1 / n as f64;
    let mut tau = DVec3::ZERO;
    for i in 0..n {
        let q = p + d * ((i as f64 + 0.5) * ds);
        tau += extinction(q.length() - EARTH_RADIUS) * ds;
    }
    DVec3::new((-tau.x).exp(), (-tau.y).exp(), (-tau.z).exp())
}

/// Radiance along unit `d` from sea level for a sun of unit irradiance above the atmosphere.
fn single_scattering(d: DVec3, sun: DVec3) -> DVec3 {
    let p0 = DVec3::new(0.0, EARTH_RADIUS + 1.0, 0.0);
    let ground = to_sphere(p0, d, EARTH_RADIUS).filter(|(t0, _)| *t0 > 0.0);
    let end = match ground {
        Some((t0, _)) => t0,
        None => to_sphere(p0, d, ATMOSPHERE_RADIUS).map_or(0.0, |(_, t1)| t1),
    };
    let cos = d.dot(sun);
    let phase_r = 3.0 / (16.0 * std::f64::consts::PI) * (1.0 + cos * cos);
    let g2 = MIE_G * MIE_G;
    let phase_m =
        (1.0 - g2) / (4.0 * std::f64::consts::PI * (1.0 + g2 - 2.0 * MIE_G * cos).powf(1.5));
    let n = 48;
    // samples denser near the observer, where the air is
    let mut l = DVec3::ZERO;
    let mut tau = DVec3::ZERO;
    let mut prev = 0.0;
    for i in 0..n {
        let s = end * ((i as f64 + 1.0) / n as f64).powi(2);
        let ds = s - prev;
        let mid = 0.5 * (s + prev);
        prev = s;
        let q = p0 + d * mid;
        let h = q.length() - EARTH_RADIUS;
        let ext = extinction(h);
        let t_view = DVec3::new(
            (-(tau.x + 0.5 * ext.x * ds)).exp(),
            (-(tau.y + 0.5 * ext.y * ds)).exp(),
            (-(tau.z + 0.5 * ext.z * ds)).exp(),
        );
        let t_sun = transmittance(q, sun);
        let r = (-h / RAYLEIGH_HEIGHT).exp();
        let m = (-h / MIE_HEIGHT).exp();
        let scatter = DVec3::from_array(RAYLEIGH) * (r * phase_r) + DVec3::splat(MIE * m * phase_m);
        l += t_view * t_sun * scatter * ds;
        tau += ext * ds;
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blender_sky() -> Sky {
        // render_blender.py's sun: 40 degrees up; its irradiance and colour
        let sun = DVec3::new(0.719_846, 0.642_788, 0.262_003);
        Sky::new(sun, DVec3::new(1.0, 0.812, 0.613) * 145.5)
    }

    #[test]
    fn a_clear_sky_lights_a_level_surface_as_blenders_does() {
        let e = blender_sky().level_irradiance();
        let blender = [7.17, 8.96, 12.69];
        for c in 0..3 {
            let r = e[c] / blender[c];
            eprintln!("channel {c}: {} vs Blender's {}", e[c], blender[c]);
            assert!(
                (0.75..1.25).contains(&r),
                "channel {c}: {} vs {}",
                e[c],
                blender[c]
            );
        }
    }

    #[test]
    fn the_zenith_is_blue_the_horizon_whiter_the_ground_dim() {
        let s = blender_sky();
        let zenith = s.radiance(DVec3::Y);
        let horizon = s.radiance(DVec3::new(-0.26, 0.02, 0.97).normalize());
        let ground = s.radiance(DVec3::new(0.0, -0.3, 1.0).normalize());
        assert!(zenith.z > zenith.x, "{zenith}");
        assert!(
            horizon.x / horizon.z > zenith.x / zenith.z,
            "{horizon} {zenith}"
        );
        assert!(ground.length() < horizon.length(), "{ground} {horizon}");
        // the table reads back what it holds
        let d = direction(s.sun, 0.3, 0.4);
        let exact = single_scattering(d, s.sun);
        assert!(exact.length() > 0.0);
    }
}
