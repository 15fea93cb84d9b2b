//! Debug view (paper Fig. 3): particles drawn as discs of their kernel size, coloured by adaptive
//! level or by shape energy, over the sky. Sequential with a depth test (strictly nearer wins),
//! so ties go to the lower particle index: deterministic.
use super::{LinearImage, PreviewParams};
use crate::error::Result;
use crate::ground::ParticleState;
use glam::{DVec3, Vec4};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParticleColor {
    /// Level 0 blue ... `max_level` red.
    Level { max_level: u32 },
    /// Shape energy (thermo.w) from 0 (blue) to `max` (red).
    ShapeEnergy,
}

fn ramp(t: f64) -> DVec3 {
    let t = t.clamp(0.0, 1.0);
    // blue -> cyan -> yellow -> red
    let stops = [
        DVec3::new(0.1, 0.2, 0.9),
        DVec3::new(0.1, 0.8, 0.9),
        DVec3::new(0.95, 0.9, 0.1),
        DVec3::new(0.9, 0.1, 0.05),
    ];
    let x = t * 3.0;
    let i = (x.floor() as usize).min(2);
    let f = x - i as f64;
    stops[i].lerp_monotonic(stops[i + 1], f)
}

/// Particles seen by the preview camera; disc radius = 0.5 h_j projected (at least one pixel).
pub fn render_particles(
    state: &ParticleState,
    params: &PreviewParams,
    h0: f64,
    color: ParticleColor,
    energy_max: f64,
) -> Result<LinearImage> {
    draw(state, params, h0, color, energy_max, false)
}

/// [`render_particles`] coloured by level, a finer level drawn over a coarser one whatever their
/// depths (the nearer of one level wins): the split particles inside a cloud show through the
/// coarse ones around it (`nimbus preview --view particles`).
pub fn render_levels(
    state: &ParticleState,
    params: &PreviewParams,
    h0: f64,
    max_level: u32,
) -> Result<LinearImage> {
    draw(
        state,
        params,
        h0,
        ParticleColor::Level { max_level },
        1.0,
        true,
    )
}

fn draw(
    state: &ParticleState,
    params: &PreviewParams,
    h0: f64,
    color: ParticleColor,
    energy_max: f64,
    levels_in_front: bool,
) -> Result<LinearImage> {
    params.validate()?;
    let (w, h) = (params.width, params.height);
    let c = &params.camera;
    let (fwd, right, up) = c.basis();
    let th = (c.fov_deg.to_radians() * 0.5).tan();
    let aspect = w as f64 / h as f64;
    let mut data = super::sky_image(params)?.data;
    let mut depth = vec![f64::INFINITY; data.len()];
    // the level of the particle drawn at each pixel (with `levels_in_front`)
    let mut drawn = vec![0u32; data.len()];
    for j in 0..state.len() {
        let p = state.pos[j];
        let rel = Vec4::from(p).truncate().as_dvec3() - c.position;
        let z = rel.dot(fwd);
        if z.is_nan() || z <= 1e-9 {
            continue;
        }
        let u = rel.dot(right) / (z * th * aspect);
        let v = rel.dot(up) / (z * th);
        let px = (u + 1.0) * 0.5 * w as f64;
        let py = (1.0 - v) * 0.5 * h as f64;
        let level = state.info.get(j).map_or(0, |i| i[1]);
        let hj = crate::ground::levels::radius(h0, level);
        let rad = (0.5 * hj / (z * th) * 0.5 * h as f64).max(0.5);
        if !(px.is_finite() && py.is_finite()) || px + rad < 0.0 || py + rad < 0.0 {
            continue;
        }
        if px - rad > w as f64 || py - rad > h as f64 {
            continue;
        }
        let t = match color {
            ParticleColor::Level { max_level } => level as f64 / max_level.max(1) as f64,
            ParticleColor::ShapeEnergy => {
                state.thermo.get(j).map_or(0.0, |t| t[3] as f64) / energy_max.max(1e-30)
            }
        };
        let col = ramp(t);
        let (x0, x1) = (
            (px - rad).floor().max(0.0) as u32,
            ((px + rad).ceil() as u32).min(w),
        );
        let (y0, y1) = (
            (py - rad).floor().max(0.0) as u32,
            ((py + rad).ceil() as u32).min(h),
        );
        for y in y0..y1 {
            for x in x0..x1 {
                let (dx, dy) = (x as f64 + 0.5 - px, y as f64 + 0.5 - py);
                if dx * dx + dy * dy > rad * rad {
                    continue;
                }
                let i = (y * w + x) as usize;
                let wins = if levels_in_front && depth[i].is_finite() {
                    level > drawn[i] || (level == drawn[i] && z < depth[i])
                } else {
                    z < depth[i]
                };
                if wins {
                    depth[i] = z;
                    drawn[i] = level;
                    // Simple shading: darker towards the disc's rim.
                    let s = 1.0 - 0.4 * (dx * dx + dy * dy) / (rad * rad);
                    data[i] = (col * s).as_vec3().extend(1.0).to_array();
                }
            }
        }
    }
    Ok(LinearImage {
        width: w,
        height: h,
        data,
    })
}

/// A key to [`ParticleColor::Level`] at the top-right corner of an image: a swatch of each
/// level's colour with its number, level 0 to `max_level` from left to right.
pub fn draw_level_legend(img: &mut image::RgbImage, max_level: u32) {
    let scale = (img.height() / 180).max(1);
    let sw = 6 * scale;
    let cell = sw + 5 * scale;
    let n = max_level + 1;
    let x0 = img.width().saturating_sub(n * cell + 2 * scale);
    let y0 = 2 * scale;
    for level in 0..n {
        let x = x0 + level * cell;
        let c = ramp(level as f64 / max_level.max(1) as f64);
        let rgb = image::Rgb([c.x, c.y, c.z].map(|v| super::encode_srgb(v.clamp(0.0, 1.0))));
        super::sheet::draw_number(img, x, y0, level, scale);
        for dy in 0..sw {
            for dx in 0..sw {
                let (px, py) = (x + dx, y0 + 7 * scale + dy);
                if px < img.width() && py < img.height() {
                    img.put_pixel(px, py, rgb);
                }
            }
        }
    }
}
