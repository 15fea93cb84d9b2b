//! CPU ray-marched preview images of a density grid, a contact sheet, and a particle debug view.
//!
//! Light model (per sample of the view ray, step of `step` voxels):
//! - extinction sigma_t = density_scale * density (Beer-Lambert), scattering sigma_s = albedo sigma_t;
//! - sun: single scattering with a Henyey-Greenstein phase function, the transmittance towards
//!   the sun read from a coarse optical-depth volume precomputed once per frame; multiple
//!   scattering approximated by Wrenninge's octaves: sum_i b^i exp(-a^i tau) HG(cos, c^i g);
//! - ambient: the sky's mean radiance, attenuated by the optical depth towards the zenith;
//! - each step is integrated analytically over its length (energy-conserving for thick media);
//! - behind the cloud: a sky gradient above the horizon and a lit ground plane (y = 0), with the
//!   clouds' shadows, below it.
//!
//! Everything is deterministic: rows are rendered in parallel, each pixel independently, and the
//! start offset that hides banding is a hash of the pixel coordinates.
pub mod movie;
pub mod particles;
pub mod sheet;
mod volume;

pub use sheet::{contact_sheet, write_contact_sheet};

use crate::config::PreviewConfig;
use crate::error::{Error, Result};
use crate::splat::SparseGrid;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use volume::Volume;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub position: [f64; 3],
    pub look_at: [f64; 3],
    /// Vertical field of view, degrees.
    pub fov_deg: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct PreviewParams {
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    /// Unit vector towards the sun.
    pub sun_direction: [f64; 3],
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
    /// Multiplier before tone mapping.
    pub exposure: f64,
}

impl PreviewParams {
    /// Parameters from the shot config; the camera is auto-framed from `domain_size` when the
    /// config has none.
    pub fn from_config(cfg: &PreviewConfig, domain_size: [f64; 3]) -> Result<Self> {
        let [w, h] = cfg.resolution;
        let camera = match &cfg.camera {
            Some(c) => Camera {
                position: c.position,
                look_at: c.look_at,
                fov_deg: c.fov_deg,
            },
            None => auto_camera(domain_size, w as f64 / h.max(1) as f64, 45.0),
        };
        let p = Self {
            width: w,
            height: h,
            camera,
            sun_direction: normalize(cfg.sun_direction),
            sun_color: cfg.sun_color,
            sun_intensity: cfg.sun_intensity,
            density_scale: cfg.density_scale,
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
            sun_direction: normalize(d.sun_direction),
            sun_color: d.sun_color,
            sun_intensity: d.sun_intensity,
            density_scale: d.density_scale,
            albedo: 0.98,
            phase_g: 0.5,
            octaves: 4,
            octave_a: 0.5,
            octave_b: 0.5,
            octave_c: 0.5,
            ambient: 1.0,
            step: 0.75,
            exposure: 1.0,
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
        let fwd = sub(c.look_at, c.position);
        if !c.position.iter().chain(&c.look_at).all(|v| v.is_finite()) || dot(fwd, fwd) <= 0.0 {
            return bad("camera position and look_at must be finite and distinct".into());
        }
        let s = self.sun_direction;
        if !s.iter().all(|v| v.is_finite()) || (dot(s, s) - 1.0).abs() > 1e-6 {
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
    pub fn ray(&self, x: u32, y: u32) -> [f64; 3] {
        let c = &self.camera;
        let fwd = normalize(sub(c.look_at, c.position));
        let mut right = cross(fwd, [0.0, 1.0, 0.0]);
        if dot(right, right) < 1e-12 {
            right = cross(fwd, [0.0, 0.0, -1.0]);
        }
        let right = normalize(right);
        let up = cross(right, fwd);
        let th = (c.fov_deg.to_radians() * 0.5).tan();
        let aspect = self.width as f64 / self.height as f64;
        let u = ((x as f64 + 0.5) / self.width as f64 * 2.0 - 1.0) * th * aspect;
        let v = (1.0 - (y as f64 + 0.5) / self.height as f64 * 2.0) * th;
        normalize([0, 1, 2].map(|a| fwd[a] + u * right[a] + v * up[a]))
    }
}

/// The domain `[0, size]` seen from the side (+z looking towards -z), ground at the bottom: the
/// front face fits the frame with a 5% margin.
pub fn auto_camera(size: [f64; 3], aspect: f64, fov_deg: f64) -> Camera {
    let tv = (fov_deg.to_radians() * 0.5).tan();
    let th = tv * aspect.max(1e-3);
    let dist = (0.5 * size[0] / th).max(0.5 * size[1] / tv) * 1.05;
    let centre = [0.5 * size[0], 0.5 * size[1], 0.5 * size[2]];
    Camera {
        position: [centre[0], centre[1], size[2] + dist],
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

    /// Exposure, a filmic curve (ACES fit) and the sRGB transfer function, 8 bits.
    pub fn to_srgb8(&self, exposure: f64) -> image::RgbImage {
        let mut out = image::RgbImage::new(self.width, self.height);
        for (px, v) in out.pixels_mut().zip(&self.data) {
            *px = image::Rgb([0, 1, 2].map(|c| encode_srgb(tonemap(v[c] as f64 * exposure))));
        }
        out
    }
}

fn tonemap(x: f64) -> f64 {
    let x = x.max(0.0);
    ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)
}

fn encode_srgb(x: f64) -> u8 {
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// Radiance of the sky gradient towards `dir` (above the horizon).
fn sky_gradient(dir: [f64; 3]) -> [f64; 3] {
    let zenith = [0.16, 0.34, 0.75];
    let horizon = [0.62, 0.74, 0.90];
    let t = dir[1].clamp(0.0, 1.0).sqrt();
    [0, 1, 2].map(|a| horizon[a] + (zenith[a] - horizon[a]) * t)
}

/// Mean sky radiance: the ambient light on clouds and ground.
fn sky_ambient() -> [f64; 3] {
    sky_gradient([0.0, 0.5, 0.0])
}

const GROUND_ALBEDO: [f64; 3] = [0.20, 0.22, 0.16];

/// What a ray from `origin` along `dir` sees without any cloud: the sky above the horizon, the
/// sunlit ground plane y = 0 below it (faded into the horizon haze with distance).
pub fn sky(params: &PreviewParams, origin: [f64; 3], dir: [f64; 3]) -> [f64; 3] {
    background(params, origin, dir, |_| 1.0)
}

fn background(
    params: &PreviewParams,
    origin: [f64; 3],
    dir: [f64; 3],
    sun_transmittance: impl Fn([f64; 3]) -> f64,
) -> [f64; 3] {
    if dir[1] < -1e-9 && origin[1] > 0.0 {
        let t = -origin[1] / dir[1];
        let p = [origin[0] + t * dir[0], 0.0, origin[2] + t * dir[2]];
        let s = params.sun_direction;
        let sun = params.sun_intensity * s[1].max(0.0) * sun_transmittance(p);
        let amb = sky_ambient();
        let haze = 1.0 - (-t / (50.0 * origin[1].max(1e-6))).exp();
        let hz = sky_gradient([0.0, 0.0, 0.0]);
        return [0, 1, 2].map(|a| {
            let g = GROUND_ALBEDO[a] / std::f64::consts::PI
                * (sun * params.sun_color[a] + std::f64::consts::PI * amb[a]);
            g + (hz[a] - g) * haze
        });
    }
    sky_gradient(dir)
}

fn hg(cos: f64, g: f64) -> f64 {
    let d = 1.0 + g * g - 2.0 * g * cos;
    (1.0 - g * g) / (4.0 * std::f64::consts::PI * d * d.sqrt())
}

/// Renders the density grid (see the module docs); an empty grid gives `sky` at every pixel.
pub fn render(grid: &SparseGrid<f32>, params: &PreviewParams) -> Result<LinearImage> {
    params.validate()?;
    let v = grid.transform.voxel_size;
    if !(v.is_finite() && v > 0.0) {
        return Err(Error::InvalidInput(format!(
            "preview: grid voxel size {v} must be > 0"
        )));
    }
    let vol = Volume::new(grid, params.sun_direction);
    let w = params.width;
    let rows: Vec<Vec<[f32; 4]>> = (0..params.height)
        .into_par_iter()
        .map(|y| (0..w).map(|x| shade_pixel(&vol, params, x, y)).collect())
        .collect();
    Ok(LinearImage {
        width: w,
        height: params.height,
        data: rows.into_iter().flatten().collect(),
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

fn shade_pixel(vol: &Volume, p: &PreviewParams, x: u32, y: u32) -> [f32; 4] {
    let o = p.camera.position;
    let d = p.ray(x, y);
    let (l, trans) = march(vol, p, o, d, hash01(x, y));
    let bg = if vol.is_empty() {
        sky(p, o, d)
    } else {
        let cell_m = vol.coarse.stride as f64 * vol.voxel;
        background(p, o, d, |g| {
            let q = [0, 1, 2].map(|a| (g[a] - vol.origin[a]) / vol.voxel);
            let tau = vol
                .coarse
                .march(vol.coarse.to_cell(q), p.sun_direction, cell_m);
            (-p.density_scale * tau).exp()
        })
    };
    [
        (l[0] + trans * bg[0]) as f32,
        (l[1] + trans * bg[1]) as f32,
        (l[2] + trans * bg[2]) as f32,
        (1.0 - trans) as f32,
    ]
}

/// In-scattered radiance and transmittance along the ray through the volume (up to the ground).
fn march(
    vol: &Volume,
    p: &PreviewParams,
    o: [f64; 3],
    d: [f64; 3],
    jitter: f64,
) -> ([f64; 3], f64) {
    let mut l = [0.0; 3];
    let mut trans = 1.0f64;
    if vol.is_empty() || p.density_scale == 0.0 {
        return (l, trans);
    }
    // Index space: the transform is a uniform scale, so directions are unchanged.
    let qo = [0, 1, 2].map(|a| (o[a] - vol.origin[a]) / vol.voxel);
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
    // Stop at the ground plane.
    if d[1] < 0.0 && o[1] > 0.0 {
        t1 = t1.min(-o[1] / d[1] / vol.voxel);
    }
    if t0 >= t1 {
        return (l, trans);
    }
    let sun = p.sun_direction;
    let cos = dot(d, sun);
    let mut sun_phase = [0.0; 16];
    for (i, ph) in sun_phase.iter_mut().enumerate().take(p.octaves as usize) {
        *ph = p.octave_b.powi(i as i32) * hg(cos, p.phase_g * p.octave_c.powi(i as i32));
    }
    let amb = sky_ambient();
    let step = p.step;
    let step_m = step * vol.voxel;
    let mut t = t0 + jitter * step;
    while t < t1 {
        let q = [qo[0] + d[0] * t, qo[1] + d[1] * t, qo[2] + d[2] * t];
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
            let mut sun_l = 0.0;
            let mut a_i = 1.0;
            for ph in &sun_phase[..p.octaves as usize] {
                sun_l += ph * (-a_i * tau_sun).exp();
                a_i *= p.octave_a;
            }
            let amb_t = (-0.5 * p.density_scale * vol.coarse.tau_up_at(q)).exp() * p.ambient;
            let step_t = (-sigma_t * step_m).exp();
            // Integral of trans * exp(-sigma_t s) * S over the step, S = sigma_s * radiance.
            let k = trans * (1.0 - step_t) / sigma_t * sigma_s;
            for c in 0..3 {
                let radiance = sun_l * p.sun_intensity * p.sun_color[c] + amb_t * amb[c];
                l[c] += k * radiance;
            }
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

/// Renders one frame's preview to `<out>/preview/<shot>.<frame>.png` (and `.exr` when `exr`),
/// returning the PNG path.
pub fn write_frame_preview(
    grid: &SparseGrid<f32>,
    params: &PreviewParams,
    out_dir: &Path,
    shot: &str,
    frame: u32,
    padding: u32,
    exr: bool,
) -> Result<PathBuf> {
    let img = render(grid, params)?;
    let dir = out_dir.join("preview");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let stem = format!("{shot}.{frame:0width$}", width = padding as usize);
    let png = dir.join(format!("{stem}.png"));
    crate::io::atomic::write_atomic(&png, &png_bytes(&img.to_srgb8(params.exposure))?)?;
    if exr {
        write_exr(&dir.join(format!("{stem}.exr")), &img)?;
    }
    Ok(png)
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
pub(crate) fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    if n > 0.0 && n.is_finite() {
        a.map(|v| v / n)
    } else {
        a
    }
}
