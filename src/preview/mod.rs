//! CPU ray-marched preview images of a density grid, a contact sheet, and a particle debug view.
//!
//! The default scene is `tools/render_blender.py`'s, so that a preview shows what the Blender
//! render of the same frame shows (docs/RENDERING.md measures how close): its camera (35 mm lens,
//! 36 mm sensor, from the ground in front and to the right, framing the domain with a 10%
//! margin), its sun (40 degrees up, the Nishita sky's sun: warm white, irradiance 145.5), its
//! clear sky (`sky`: Nishita's model), a white cloud with forward scattering (Henyey-Greenstein
//! g = 0.8), the density grid's physical extinction (`density_mode: physical`,
//! docs/RENDERING.md "Physical optics") and Blender's Filmic view transform at its exposure.
//!
//! Light model (per sample of the view ray, step of `step` voxels):
//! - extinction sigma_t = density_scale * density (Beer-Lambert), scattering sigma_s = albedo sigma_t;
//! - sun: single scattering with a Henyey-Greenstein phase function, the transmittance towards
//!   the sun read from a coarse optical-depth volume precomputed once per frame; multiple
//!   scattering approximated by Wrenninge's octaves: sum_i b^i exp(-a^i tau) HG(cos, c^i g);
//! - ambient: the sky's mean radiance over the upper and the lower hemisphere, attenuated by
//!   the optical depths towards the zenith and the nadir through the same octaves;
//! - each step is integrated analytically over its length (energy-conserving for thick media);
//! - behind the cloud: the sky.
//!
//! Everything is deterministic: rows are rendered in parallel, each pixel independently, and the
//! start offset that hides banding is a hash of the pixel coordinates.
pub mod movie;
pub mod overlay;
pub mod particles;
pub mod sheet;
pub mod sky;
mod volume;

pub use sheet::{contact_sheet, write_contact_sheet};

use crate::config::{DensityMode, PreviewConfig, ShotConfig};
use crate::error::{Error, Result};
use crate::ground::SparseGrid;
use glam::DVec3;
use rayon::prelude::*;
pub use sky::Sky;
use std::path::{Path, PathBuf};
use volume::Volume;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub position: DVec3,
    pub look_at: DVec3,
    /// Vertical field of view, degrees.
    pub fov_deg: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct PreviewParams {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    /// Unit vector towards the sun.
    pub sun_direction: DVec3,
    pub sun_color: [f64; 3],
    pub sun_intensity: f64,
    /// Extinction per unit of density per metre.
    pub density_scale: f64,
    /// Single-scattering albedo (clouds: ~1).
    pub albedo: f64,
    /// Henyey-Greenstein anisotropy (clouds scatter forward).
    pub phase_g: f64,
    /// Multiple-scattering octaves and their attenuation of extinction (a), contribution (b)
    /// and anisotropy (c).
    pub octaves: u32,
    pub octave_a: f64,
    pub octave_b: f64,
    pub octave_c: f64,
    /// Scale of the sky's ambient light on the cloud.
    pub ambient: f64,
    /// Ray-march step in voxels.
    pub step: f64,
    /// Multiplier before the view transform (render_blender.py's film exposure, 2^-2.4).
    pub exposure: f64,
}

/// render_blender.py's film exposure, in stops.
pub const EXPOSURE_STOPS: f64 = -2.4;

impl PreviewParams {
    /// Parameters of a shot: its `output.preview`, domain and the density grid's physical
    /// extinction (`export.optics`).
    pub fn for_shot(cfg: &ShotConfig) -> Result<Self> {
        let k = crate::export::optics::Optics::from_config(cfg).extinction_per_metre;
        Self::from_config(&cfg.output.preview, cfg.domain.size, k)
    }

    /// Parameters from the preview config; the camera is auto-framed from `domain_size` when the
    /// config has none; `extinction_per_metre` is the density grid's physical extinction per
    /// unit (`density_mode: physical`).
    pub fn from_config(
        cfg: &PreviewConfig,
        domain_size: [f64; 3],
        extinction_per_metre: f64,
    ) -> Result<Self> {
        let [w, h] = cfg.resolution;
        let camera = match &cfg.camera {
            Some(c) => Camera {
                position: c.position.into(),
                look_at: c.look_at.into(),
                fov_deg: c.fov_deg,
            },
            None => blender_camera(DVec3::ZERO, domain_size.into(), w as f64 / h.max(1) as f64),
        };
        let p = Self {
            width: w,
            height: h,
            camera,
            sun_direction: normalize(cfg.sun_direction.into()),
            sun_color: cfg.sun_color,
            sun_intensity: cfg.sun_intensity,
            density_scale: match cfg.density_mode {
                DensityMode::Physical => extinction_per_metre,
                DensityMode::Fixed => cfg.density_scale,
            },
            ..Self::defaults(camera, w, h)
        };
        p.validate()?;
        Ok(p)
    }

    /// Default lighting with a given camera and resolution.
    pub fn defaults(camera: Camera, width: u32, height: u32) -> Self {
        let d = PreviewConfig::default();
        Self {
            width,
            height,
            camera,
            sun_direction: normalize(d.sun_direction.into()),
            sun_color: d.sun_color,
            sun_intensity: d.sun_intensity,
            density_scale: d.density_scale,
            // Blender's Principled Volume, white: no absorption; anisotropy 0.8
            albedo: 1.0,
            phase_g: 0.8,
            octaves: OCTAVES,
            octave_a: OCTAVE_A,
            octave_b: OCTAVE_B,
            octave_c: OCTAVE_C,
            ambient: 1.0,
            step: 0.75,
            exposure: EXPOSURE_STOPS.exp2(),
        }
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidInput(format!("preview: {m}")));
        if !(1..=16384).contains(&self.width) || !(1..=16384).contains(&self.height) {
            return bad(format!(
                "resolution {}x{} must be within 1..=16384",
                self.width, self.height
            ));
        }
        let c = &self.camera;
        if !(c.fov_deg > 0.0 && c.fov_deg < 180.0) {
            return bad(format!("camera fov_deg {} must be in (0, 180)", c.fov_deg));
        }
        let fwd = c.look_at - c.position;
        if !(c.position.is_finite() && c.look_at.is_finite()) || fwd.dot(fwd) <= 0.0 {
            return bad("camera position and look_at must be finite and distinct".into());
        }
        let s = self.sun_direction;
        if !s.is_finite() || (s.dot(s) - 1.0).abs() > 1e-6 {
            return bad("sun_direction must be a non-zero vector".into());
        }
        let nonneg = [
            ("sun_intensity", self.sun_intensity),
            ("density_scale", self.density_scale),
            ("ambient", self.ambient),
            ("exposure", self.exposure),
            ("sun_color", self.sun_color[0]),
            ("sun_color", self.sun_color[1]),
            ("sun_color", self.sun_color[2]),
        ];
        for (name, v) in nonneg {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{name} must be >= 0, got {v}"));
            }
        }
        if !(0.0..=1.0).contains(&self.albedo) || self.phase_g.is_nan() || self.phase_g.abs() >= 1.0
        {
            return bad("albedo must be in [0, 1] and |phase_g| < 1".into());
        }
        if !(self.step.is_finite() && self.step >= 0.05) {
            return bad(format!("step must be >= 0.05 voxels, got {}", self.step));
        }
        if self.octaves == 0 || self.octaves > 16 {
            return bad(format!("octaves must be in 1..=16, got {}", self.octaves));
        }
        Ok(())
    }

    /// Unit ray direction through the centre of pixel (x, y).
    pub fn ray(&self, x: u32, y: u32) -> DVec3 {
        let c = &self.camera;
        let (fwd, right, up) = c.basis();
        let th = (c.fov_deg.to_radians() * 0.5).tan();
        let aspect = self.width as f64 / self.height as f64;
        let u = ((x as f64 + 0.5) / self.width as f64 * 2.0 - 1.0) * th * aspect;
        let v = (1.0 - (y as f64 + 0.5) / self.height as f64 * 2.0) * th;
        normalize(fwd + u * right + v * up)
    }
}

impl Camera {
    /// Unit (forward, right, up): looking at `look_at`, y up (z when looking straight up or
    /// down).
    pub fn basis(&self) -> (DVec3, DVec3, DVec3) {
        let fwd = normalize(self.look_at - self.position);
        let mut right = fwd.cross(DVec3::Y);
        if right.dot(right) < 1e-12 {
            right = fwd.cross(DVec3::NEG_Z);
        }
        let right = normalize(right);
        (fwd, right, right.cross(fwd))
    }
}

/// Multiple-scattering octaves of the preview: Wrenninge's a = b = 0.5 over 8 octaves (a thick
/// cloud's shaded side is lit by light that scattered many times), the anisotropy falling
/// fast (c = 0.2: diffuse light leaves the lit side towards the camera). Chosen against Cycles
/// at render_blender.py's 256 volume bounces on quickstart's last frame (docs/RENDERING.md
/// "Previews that show what the render shows").
pub const OCTAVES: u32 = 8;
pub const OCTAVE_A: f64 = 0.5;
pub const OCTAVE_B: f64 = 0.5;
pub const OCTAVE_C: f64 = 0.2;

/// tools/render_blender.py's camera for a box `[lo, hi]` (nimbus frame, y up): from the ground
/// (2% of the box's height up), in front of the box and a little to its right (heading (0.25,
/// 0, 1), Blender's (0.25, -1, 0)), looking at the box's centre, a 35 mm lens on a 36 mm
/// sensor fitted to the wider side of the image, at the nearest distance where all eight
/// corners fit the frame with a 10% margin (bisection, as the script does).
pub fn blender_camera(lo: DVec3, hi: DVec3, aspect: f64) -> Camera {
    let aspect = aspect.max(1e-6);
    let centre = 0.5 * (lo + hi);
    let size = hi - lo;
    let fov_wide = 2.0 * (36.0f64 / (2.0 * 35.0)).atan();
    let fov_x = if aspect >= 1.0 {
        fov_wide
    } else {
        2.0 * ((fov_wide / 2.0).tan() * aspect).atan()
    };
    let fov_y = 2.0 * ((fov_x / 2.0).tan() / aspect).atan();
    let (tx, ty) = ((fov_x / 2.0).tan() / 1.1, (fov_y / 2.0).tan() / 1.1);
    let heading = normalize(DVec3::new(0.25, 0.0, 1.0));
    let height = lo.y + 0.02 * size.y;
    let position = |dist: f64| DVec3::new(centre.x, height, centre.z) + heading * dist;
    let fits = |dist: f64| {
        let cam = Camera {
            position: position(dist),
            look_at: centre,
            fov_deg: fov_y.to_degrees(),
        };
        let (fwd, right, up) = cam.basis();
        (0..8).all(|i| {
            let corner =
                DVec3::select(glam::BVec3::new(i & 1 == 1, i & 2 == 2, i & 4 == 4), hi, lo);
            let c = corner - cam.position;
            let depth = c.dot(fwd);
            depth > 0.0 && c.dot(right).abs() <= tx * depth && c.dot(up).abs() <= ty * depth
        })
    };
    let span = size.length().max(1e-6);
    let (mut near, mut far) = (1e-3 * span, span);
    while !fits(far) && far < 1e12 {
        far *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (near + far);
        if fits(mid) {
            far = mid;
        } else {
            near = mid;
        }
    }
    Camera {
        position: position(far),
        look_at: centre,
        fov_deg: fov_y.to_degrees(),
    }
}

/// The domain `[0, size]` seen from the side (+z looking towards -z), ground at the bottom: the
/// front face fits the frame with a 5% margin.
pub fn auto_camera(size: [f64; 3], aspect: f64, fov_deg: f64) -> Camera {
    let tv = (fov_deg.to_radians() * 0.5).tan();
    let th = tv * aspect.max(1e-3);
    let dist = (0.5 * size[0] / th).max(0.5 * size[1] / tv) * 1.05;
    let centre = 0.5 * DVec3::from(size);
    Camera {
        position: DVec3::new(centre.x, centre.y, size[2] + dist),
        look_at: centre,
        fov_deg,
    }
}

/// Linear RGBA image (alpha = 1 - transmittance of the volume along the pixel's ray).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<[f32; 4]>,
}

impl LinearImage {
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        self.data[(y * self.width + x) as usize]
    }

    /// Exposure and Blender's Filmic view transform (base contrast) for an sRGB display, 8
    /// bits, channel by channel (`filmic`).
    pub fn to_srgb8(&self, exposure: f64) -> image::RgbImage {
        let mut out = image::RgbImage::new(self.width, self.height);
        for (px, v) in out.pixels_mut().zip(&self.data) {
            *px = image::Rgb([0, 1, 2].map(|c| filmic8(v[c] as f64 * exposure)));
        }
        out
    }
}

impl LinearImage {
    /// Blender's Standard view transform (the sRGB transfer function, clipped at 1), 8 bits:
    /// for debug views whose colours are display colours (the particle view).
    pub fn to_srgb8_standard(&self) -> image::RgbImage {
        let mut out = image::RgbImage::new(self.width, self.height);
        for (px, v) in out.pixels_mut().zip(&self.data) {
            *px = image::Rgb([0, 1, 2].map(|c| encode_srgb((v[c] as f64).clamp(0.0, 1.0))));
        }
        out
    }
}

fn encode_srgb(x: f64) -> u8 {
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// Blender 3.4.1's Filmic view transform, look "None", sRGB display: the 8-bit output for
/// scene-linear grey 0.18 x 2^s at s = -12, -11.8125, ..., 12 (129 values, 0.1875 stops apart),
/// measured by saving a float ramp through Blender's colour management (`Image.save_render`).
/// Filmic also desaturates bright colours (a 3-D table); the preview applies the grey curve to
/// each channel, which keeps white clouds white and leaves the sky a little more saturated.
const FILMIC_8BIT: [u8; 129] = [
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 7, 8, 9,
    10, 11, 12, 13, 15, 16, 18, 20, 22, 24, 26, 28, 31, 34, 37, 40, 43, 47, 51, 55, 59, 64, 69, 74,
    79, 84, 90, 96, 102, 108, 115, 121, 128, 134, 141, 147, 153, 160, 166, 172, 178, 184, 190, 195,
    200, 205, 210, 214, 219, 222, 226, 229, 233, 236, 238, 241, 243, 245, 247, 248, 250, 251, 252,
    253, 254, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255,
    255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255,
];

/// The Filmic display value (0 to 1, sRGB-encoded) of scene-linear `x`.
pub fn filmic(x: f64) -> f64 {
    // NaN and non-positive: black
    if x.is_nan() || x <= 0.0 {
        return 0.0;
    }
    let s = ((x / 0.18).log2() + 12.0) / 0.1875;
    if s <= 0.0 {
        return 0.0;
    }
    let i = (s.floor() as usize).min(FILMIC_8BIT.len() - 2);
    let f = (s - i as f64).min(1.0);
    let (a, b) = (FILMIC_8BIT[i] as f64, FILMIC_8BIT[i + 1] as f64);
    (a + f * (b - a)) / 255.0
}

fn filmic8(x: f64) -> u8 {
    (filmic(x) * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

fn hg(cos: f64, g: f64) -> f64 {
    let d = 1.0 + g * g - 2.0 * g * cos;
    (1.0 - g * g) / (4.0 * std::f64::consts::PI * d * d.sqrt())
}

impl PreviewParams {
    /// The clear sky of these parameters' sun (`sky::Sky`).
    pub fn sky(&self) -> Sky {
        Sky::new(
            self.sun_direction,
            DVec3::from(self.sun_color) * self.sun_intensity,
        )
    }
}

/// Renders the density grid (see the module docs); an empty grid gives the sky at every pixel.
pub fn render(grid: &SparseGrid<f32>, params: &PreviewParams) -> Result<LinearImage> {
    params.validate()?;
    let v = grid.transform.voxel_size;
    if !(v.is_finite() && v > 0.0) {
        return Err(Error::InvalidInput(format!(
            "preview: grid voxel size {v} must be > 0"
        )));
    }
    let vol = Volume::new(grid, params.sun_direction);
    let sky = params.sky();
    let w = params.width;
    let rows: Vec<Vec<[f32; 4]>> = (0..params.height)
        .into_par_iter()
        .map(|y| {
            (0..w)
                .map(|x| shade_pixel(&vol, &sky, params, x, y))
                .collect()
        })
        .collect();
    Ok(LinearImage {
        width: w,
        height: params.height,
        data: rows.into_iter().flatten().collect(),
    })
}

/// The sky alone, as `render` draws it behind the cloud.
pub fn sky_image(params: &PreviewParams) -> Result<LinearImage> {
    params.validate()?;
    let sky = params.sky();
    let data = (0..params.height)
        .flat_map(|y| (0..params.width).map(move |x| (x, y)))
        .map(|(x, y)| {
            sky.radiance(params.ray(x, y))
                .as_vec3()
                .extend(0.0)
                .to_array()
        })
        .collect();
    Ok(LinearImage {
        width: params.width,
        height: params.height,
        data,
    })
}

/// Deterministic per-pixel offset in [0, 1).
fn hash01(x: u32, y: u32) -> f64 {
    let mut h = (x as u64) << 32 | y as u64;
    h = (h ^ (h >> 33)).wrapping_mul(0xff51_afd7_ed55_8ccd);
    h = (h ^ (h >> 33)).wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

fn shade_pixel(vol: &Volume, sky: &Sky, p: &PreviewParams, x: u32, y: u32) -> [f32; 4] {
    let o = p.camera.position;
    let d = p.ray(x, y);
    let (l, trans) = march(vol, sky, p, o, d, hash01(x, y));
    let c = l + trans * sky.radiance(d);
    c.as_vec3().extend((1.0 - trans) as f32).to_array()
}

/// In-scattered radiance and transmittance along the ray through the volume.
fn march(
    vol: &Volume,
    sky: &Sky,
    p: &PreviewParams,
    o: DVec3,
    d: DVec3,
    jitter: f64,
) -> (DVec3, f64) {
    let mut l = DVec3::ZERO;
    let mut trans = 1.0f64;
    if vol.is_empty() || p.density_scale == 0.0 {
        return (l, trans);
    }
    // Index space: the transform is a uniform scale, so directions are unchanged.
    let qo = (o - vol.origin) / vol.voxel;
    let (blo, bhi) = vol.index_box();
    let mut t0 = 0.0f64;
    let mut t1 = f64::INFINITY;
    for a in 0..3 {
        if d[a].abs() < 1e-12 {
            if qo[a] < blo[a] || qo[a] > bhi[a] {
                return (l, trans);
            }
        } else {
            let (mut ta, mut tb) = ((blo[a] - qo[a]) / d[a], (bhi[a] - qo[a]) / d[a]);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
        }
    }
    if t0 >= t1 {
        return (l, trans);
    }
    let sun = p.sun_direction;
    let cos = d.dot(sun);
    let mut sun_phase = [0.0; 16];
    for (i, ph) in sun_phase.iter_mut().enumerate().take(p.octaves as usize) {
        *ph = p.octave_b.powi(i as i32) * hg(cos, p.phase_g * p.octave_c.powi(i as i32));
    }
    let amb_norm: f64 = (0..p.octaves as i32).map(|i| p.octave_b.powi(i)).sum();
    let step = p.step;
    let step_m = step * vol.voxel;
    let mut t = t0 + jitter * step;
    while t < t1 {
        let q = qo + d * t;
        if !vol.maybe_dense(q) {
            // Empty leaf neighbourhood: jump to the next leaf, keeping the step phase.
            let exit = vol.leaf_exit(q, d);
            t += ((exit / step).floor() + 1.0) * step;
            continue;
        }
        let rho = vol.sample(q);
        if rho > 0.0 {
            let sigma_t = p.density_scale * rho;
            let sigma_s = p.albedo * sigma_t;
            let tau_sun = p.density_scale * vol.coarse.tau_sun_at(q);
            let (tau_up, tau_down) = (
                p.density_scale * vol.coarse.tau_up_at(q),
                p.density_scale * vol.coarse.tau_down_at(q),
            );
            // Light scattered more than once needs a cloud around it to scatter in: the higher
            // octaves are weighted by the probability of a second interaction, from the optical
            // depth of the column through this point (an optically thin wisp is single-scattering).
            let ms = 1.0 - (-(tau_up + tau_down)).exp();
            let mut sun_l = 0.0;
            let mut a_i = 1.0;
            for (i, ph) in sun_phase[..p.octaves as usize].iter().enumerate() {
                let w = if i == 0 { 1.0 } else { ms };
                sun_l += w * ph * (-a_i * tau_sun).exp();
                a_i *= p.octave_a;
            }
            // The sky lights the cloud from every side: its upper hemisphere from above, the
            // lower (the air over the dark ground) from below, each through the same octaves as
            // the sun (normalised: a thin wisp in-scatters the sky's radiance itself).
            let (mut up_t, mut down_t) = (0.0, 0.0);
            let (mut a_i, mut b_i) = (1.0, 1.0);
            for _ in 0..p.octaves {
                up_t += b_i * (-0.5 * a_i * tau_up).exp();
                down_t += b_i * (-0.5 * a_i * tau_down).exp();
                a_i *= p.octave_a;
                b_i *= p.octave_b;
            }
            let amb = 0.5 * (up_t * sky.mean_up + down_t * sky.mean_down) / amb_norm * p.ambient;
            let step_t = (-sigma_t * step_m).exp();
            // Integral of trans * exp(-sigma_t s) * S over the step, S = sigma_s * radiance.
            let k = trans * (1.0 - step_t) / sigma_t * sigma_s;
            let radiance = sun_l * p.sun_intensity * DVec3::from(p.sun_color) + amb;
            l += k * radiance;
            trans *= step_t;
            if trans < 1e-4 {
                trans = 0.0;
                break;
            }
        }
        t += step;
    }
    (l, trans)
}

/// PNG bytes (sRGB, 8-bit RGB).
pub fn png_bytes(img: &image::RgbImage) -> Result<Vec<u8>> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| Error::Runtime(format!("png encoding: {e}")))?;
    Ok(out)
}

/// Writes a linear RGBA float EXR (ZIP-compressed scanlines), atomically.
pub fn write_exr(path: &Path, img: &LinearImage) -> Result<()> {
    use exr::prelude::*;
    let w = img.width as usize;
    let channels = SpecificChannels::rgba(|Vec2(x, y): Vec2<usize>| {
        let v = img.data[y * w + x];
        (v[0], v[1], v[2], v[3])
    });
    let mut layer = Layer::new(
        (w, img.height as usize),
        LayerAttributes::named("preview"),
        Encoding::SMALL_LOSSLESS,
        channels,
    );
    layer.encoding.line_order = LineOrder::Increasing;
    let image = Image::from_layer(layer);
    crate::io::atomic::write_atomic_with(path, |f| {
        image
            .write()
            .to_buffered(f)
            .map_err(|e| std::io::Error::other(e.to_string()))
    })
}

/// Renders one frame's preview to `png` (and the `.exr` beside it when `exr`), returning the
/// PNG path (a run's `preview/<shot>.<frame>.png`).
pub fn write_frame_preview(
    grid: &SparseGrid<f32>,
    params: &PreviewParams,
    png: &Path,
    exr: bool,
) -> Result<PathBuf> {
    let img = render(grid, params)?;
    write_image(&img, params.exposure, png, exr)
}

/// Writes `img` to `png` (and linear to the `.exr` beside it when `exr`), atomically, making
/// the folder; returns the PNG path.
pub fn write_image(img: &LinearImage, exposure: f64, png: &Path, exr: bool) -> Result<PathBuf> {
    if let Some(dir) = png.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    crate::io::atomic::write_atomic(png, &png_bytes(&img.to_srgb8(exposure))?)?;
    if exr {
        write_exr(&png.with_extension("exr"), img)?;
    }
    Ok(png.to_path_buf())
}

/// `a` divided by its length (zero and non-finite vectors unchanged): glam's `normalize`
/// multiplies by the reciprocal, which rounds differently and would change the images.
fn normalize(a: DVec3) -> DVec3 {
    let n = a.length();
    if n > 0.0 && n.is_finite() {
        a / n
    } else {
        a
    }
}
