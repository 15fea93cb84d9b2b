//! Debug overlays drawn into a rendered preview (`nimbus preview --view`, and
//! `output.preview.source_overlay`): the heat sources' footprints and wireframes
//! ([`sources`]) and the target volume as a ghost ([`target`]), in the preview's own camera so
//! that they line up with the cloud.
//!
//! Everything is composited in linear RGB on the [`LinearImage`] before the sRGB encoding. The
//! ground (y = 0) lies behind every cloud (nothing is below it), so a footprint tints what the
//! cloud lets through of the background, `(1 - alpha)`; wires and the ghost are in the air and
//! drawn over the cloud (x-ray), as a viewport's debug overlay is, so that a target or source
//! hidden inside the cloud still shows.
pub mod sources;
pub mod target;

use super::{LinearImage, PreviewParams};
use glam::DVec3;

/// Colour of source k (linear RGB): distinct from the sky's blue and the cloud's white.
pub const PALETTE: [DVec3; 8] = [
    DVec3::new(1.0, 0.32, 0.02),
    DVec3::new(0.85, 0.05, 0.55),
    DVec3::new(0.15, 0.75, 0.05),
    DVec3::new(1.0, 0.8, 0.02),
    DVec3::new(0.8, 0.02, 0.02),
    DVec3::new(0.4, 0.08, 0.85),
    DVec3::new(0.02, 0.6, 0.5),
    DVec3::new(0.45, 0.2, 0.03),
];

/// Pixel coordinates (x right, y down, pixel centres at +0.5) and depth along the view axis of
/// a world point, the inverse of [`PreviewParams::ray`]; `None` behind the camera.
pub fn project(params: &PreviewParams, p: DVec3) -> Option<(f64, f64, f64)> {
    let c = &params.camera;
    let (fwd, right, up) = c.basis();
    let rel = p - c.position;
    let z = rel.dot(fwd);
    if z.is_nan() || z <= 1e-6 {
        return None;
    }
    let th = (c.fov_deg.to_radians() * 0.5).tan();
    let aspect = params.width as f64 / params.height as f64;
    let u = rel.dot(right) / (z * th * aspect);
    let v = rel.dot(up) / (z * th);
    Some((
        (u + 1.0) * 0.5 * params.width as f64,
        (1.0 - v) * 0.5 * params.height as f64,
        z,
    ))
}

/// Where the ray through pixel (x, y) meets the ground y = 0 inside the domain's footprint
/// `[0, size_x] x [0, size_z]`, if it does.
pub fn ground_hit(params: &PreviewParams, size: [f64; 3], x: u32, y: u32) -> Option<DVec3> {
    let o = params.camera.position;
    let d = params.ray(x, y);
    if o.y <= 0.0 || d.y >= -1e-12 {
        return None;
    }
    let p = o + d * (-o.y / d.y);
    ((0.0..=size[0]).contains(&p.x) && (0.0..=size[2]).contains(&p.z)).then_some(p)
}

/// Line width in pixels for an image `height` pixels tall (2 at 360).
pub fn line_width(height: u32) -> f64 {
    (height as f64 / 180.0).max(1.0)
}

/// The domain's box `[0, size]` as faint white wires: where the ground and the faces are.
pub fn draw_domain_box(img: &mut LinearImage, params: &PreviewParams, size: [f64; 3]) {
    let corner = |i: usize| {
        DVec3::new(
            if i & 1 == 1 { size[0] } else { 0.0 },
            if i & 2 == 2 { size[1] } else { 0.0 },
            if i & 4 == 4 { size[2] } else { 0.0 },
        )
    };
    let width = 0.5 * line_width(img.height);
    for i in 0..8usize {
        for bit in [1, 2, 4] {
            if i & bit == 0 {
                draw_segment(
                    img,
                    params,
                    corner(i),
                    corner(i | bit),
                    DVec3::ONE,
                    0.35,
                    width,
                );
            }
        }
    }
}

/// The scene-linear radiance an overlay colour is drawn with. Overlay colours are given as they
/// should look (display-referred, 0 to 1); the previews' radiances are physical (a sun of
/// irradiance 145.5, exposure 2^-2.4, Filmic), under which a radiance of 1 is a dark grey. A
/// colour of 1 becomes 3.75 stops over Filmic's middle grey after the exposure: near its white.
pub fn display_color(color: DVec3, params: &PreviewParams) -> DVec3 {
    color * (0.18 * 3.75f64.exp2() / params.exposure)
}

/// Blends `color` (display-referred, `display_color`) over pixel i with opacity `a` (alpha
/// channel: at least `a`).
pub fn blend(img: &mut LinearImage, params: &PreviewParams, i: usize, color: DVec3, a: f64) {
    let color = display_color(color, params);
    let a = a.clamp(0.0, 1.0) as f32;
    let px = &mut img.data[i];
    for (c, v) in px.iter_mut().zip(color.as_vec3().to_array()) {
        *c += (v - *c) * a;
    }
    px[3] = px[3].max(a);
}

/// Draws the world segment a-b, `width` pixels wide with soft edges, clipped to the near plane
/// and the image.
pub fn draw_segment(
    img: &mut LinearImage,
    params: &PreviewParams,
    a: DVec3,
    b: DVec3,
    color: DVec3,
    alpha: f64,
    width: f64,
) {
    // Clip to the part in front of the camera.
    let (fwd, _, _) = params.camera.basis();
    let near = 1e-3;
    let (za, zb) = (
        (a - params.camera.position).dot(fwd),
        (b - params.camera.position).dot(fwd),
    );
    if za <= near && zb <= near {
        return;
    }
    let (a, b) = if za <= near {
        (a + (b - a) * ((near - za) / (zb - za)), b)
    } else if zb <= near {
        (a, a + (b - a) * ((near - za) / (zb - za)))
    } else {
        (a, b)
    };
    let (Some((ax, ay, _)), Some((bx, by, _))) = (project(params, a), project(params, b)) else {
        return;
    };
    let (w, h) = (img.width as f64, img.height as f64);
    let r = 0.5 * width + 0.5;
    let (x0, x1) = (ax.min(bx) - r, ax.max(bx) + r);
    let (y0, y1) = (ay.min(by) - r, ay.max(by) + r);
    if !(x0.is_finite() && y0.is_finite() && x1.is_finite() && y1.is_finite()) {
        return;
    }
    if x1 < 0.0 || y1 < 0.0 || x0 > w || y0 > h {
        return;
    }
    let (dx, dy) = (bx - ax, by - ay);
    let len2 = dx * dx + dy * dy;
    for py in y0.max(0.0).floor() as u32..(y1.min(h).ceil() as u32).min(img.height) {
        for px in x0.max(0.0).floor() as u32..(x1.min(w).ceil() as u32).min(img.width) {
            let (cx, cy) = (px as f64 + 0.5, py as f64 + 0.5);
            let t = if len2 > 0.0 {
                (((cx - ax) * dx + (cy - ay) * dy) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (ex, ey) = (cx - (ax + t * dx), cy - (ay + t * dy));
            let d = (ex * ex + ey * ey).sqrt();
            // coverage: 1 within the half width, a one-pixel ramp outside it
            let cover = (0.5 * width + 0.5 - d).clamp(0.0, 1.0);
            if cover > 0.0 {
                let i = (py * img.width + px) as usize;
                blend(img, params, i, color, alpha * cover);
            }
        }
    }
}

/// Smoothstep from 0 at q = 1 to 1 at q = 0.7 and inside: the sources' falloff
/// (shaders/thermo.wgsl `edge`).
pub fn edge(q: f64) -> f64 {
    let t = ((1.0 - q) / 0.3).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}
