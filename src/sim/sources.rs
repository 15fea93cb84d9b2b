//! `physics.sources` for the thermo stage: each source packed into thermo.wgsl's `Source`
//! (shape, placement, this substep's heat and vapor rates), the heat maps of image sources
//! concatenated into one storage buffer, and the list the manifest records.
//!
//! Shapes (docs/CONFIG.md "physics.sources"): `disc`, `ellipse`, a `box` with a 2-value centre
//! and `image` act on the air from the ground up to their `height` (default
//! `physics.heat_height`); `sphere` and a `box` with a 3-value centre act where they are. Every
//! shape is full strength in its inner part and falls to 0 at its edge with a smoothstep over
//! the outer 30% (of the radius, of the normalised ellipse radius, of each half edge); distances
//! along periodic axes wrap (minimum image), so a shape across a periodic face continues on the
//! other side. An image is sampled bilinearly at its pixel centres (wrapping on periodic axes,
//! clamped on walled ones).
use crate::config::{HeatSource, ShotConfig, SourceShape};
use crate::ground::HeatMap;
use serde::{Deserialize, Serialize};

/// Most entries of `physics.sources` (the uniform's table).
pub use crate::config::MAX_SOURCES;

/// `Source.kind.x` of thermo.wgsl.
pub const KIND_DISC: u32 = 0;
pub const KIND_ELLIPSE: u32 = 1;
pub const KIND_GROUND_BOX: u32 = 2;
pub const KIND_SPHERE: u32 = 3;
pub const KIND_AIR_BOX: u32 = 4;
pub const KIND_IMAGE: u32 = 5;

/// Top of the layer of a shape in the air: no layer (f32, finite).
const NO_TOP: f32 = 3.0e38;

/// One source in thermo.wgsl's uniform (same layout as its `Source`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SourceGpu {
    /// (kind, heat-map offset, width, height) (map entries: [`HeatMaps::with_maps`]).
    pub kind: [u32; 4],
    /// (centre x, centre y, centre z, top of the heated layer) (m); y unused on the ground.
    pub center: [f32; 4],
    /// Disc, sphere: (radius, -, -); ellipse: (semi-axis x, semi-axis z, -); box: half edges
    /// (x, z, -) on the ground, (x, y, z) in the air (m).
    pub extent: [f32; 4],
    /// (cos angle, sin angle, heating K/s, vapor kg/kg/s) with the schedule of this substep.
    pub rate: [f32; 4],
}

/// The kind of a (validated) source.
pub fn kind(s: &HeatSource) -> u32 {
    match s.shape {
        SourceShape::Disc => KIND_DISC,
        SourceShape::Ellipse => KIND_ELLIPSE,
        SourceShape::Box if s.on_ground() => KIND_GROUND_BOX,
        SourceShape::Box => KIND_AIR_BOX,
        SourceShape::Sphere => KIND_SPHERE,
        SourceShape::Image => KIND_IMAGE,
    }
}

/// The sources of a shot for a substep of `dt` starting at `time`: each schedule is taken at
/// the substep's midpoint, in f64 on the host (no heat-map entries yet).
pub fn pack(cfg: &ShotConfig, dt: f64, time: f64) -> [SourceGpu; MAX_SOURCES] {
    let p = &cfg.physics;
    std::array::from_fn(|k| {
        p.sources.get(k).map_or(SourceGpu::default(), |s| {
            let at = |i: usize| s.center.get(i).copied().unwrap_or(0.0) as f32;
            let center = if s.center.len() == 3 {
                [at(0), at(1), at(2), NO_TOP]
            } else {
                let top = s.height.unwrap_or(p.heat_height) as f32;
                [at(0), 0.0, at(1), top]
            };
            let half = |i: usize| {
                s.size
                    .as_ref()
                    .and_then(|v| v.get(i))
                    .map_or(0.0, |x| (0.5 * x) as f32)
            };
            let extent = match s.shape {
                SourceShape::Disc | SourceShape::Sphere => {
                    [s.radius.unwrap_or(0.0) as f32, 0.0, 0.0, 0.0]
                }
                SourceShape::Ellipse => {
                    let r = s.radii.unwrap_or([0.0; 2]);
                    [r[0] as f32, r[1] as f32, 0.0, 0.0]
                }
                SourceShape::Box => [half(0), half(1), half(2), 0.0],
                SourceShape::Image => [0.0; 4],
            };
            let angle = s.angle.unwrap_or(0.0).to_radians();
            let envelope = s.envelope(time + 0.5 * dt);
            SourceGpu {
                kind: [kind(s), 0, 0, 0],
                center,
                extent,
                rate: [
                    angle.cos() as f32,
                    angle.sin() as f32,
                    (s.strength * envelope) as f32,
                    (s.vapor_rate() * envelope) as f32,
                ],
            }
        })
    })
}

/// The heat maps of a shot's image sources, one after the other (row-major, row = z), and
/// where each source's map starts.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HeatMaps {
    /// Every map's values; one 0 when there is none (a storage buffer cannot be empty).
    pub values: Vec<f32>,
    /// Per source index: (offset, width, height), width 0 for sources without a map.
    pub entries: Vec<[u32; 3]>,
    /// The target controller's maps when its control is on (`sim::control`): (offset, nx, nz, ny)
    /// of the per-column supply factors, rewritten every frame, followed by the same number of
    /// footprint-mask values on the other heating and by the pull field, four values per voxel
    /// (`sim::control::Target::field`).
    pub control: Option<[u32; 4]>,
    /// The target's pull: (m/s^2, reach m, cloud threshold kg/kg, voxel height m).
    pub pull: [f32; 4],
}

impl HeatMaps {
    /// The maps of a shot's sources, as the prepared shot read them (`maps[i]` for source i,
    /// `None` for a source without a heat map).
    pub fn new(maps: &[Option<HeatMap>]) -> Self {
        let mut values = Vec::new();
        let mut entries = Vec::new();
        for map in maps {
            let Some(map) = map else {
                entries.push([0; 3]);
                continue;
            };
            entries.push([values.len() as u32, map.width as u32, map.height as u32]);
            values.extend_from_slice(&map.values);
        }
        if values.is_empty() {
            values.push(0.0);
        }
        Self {
            values,
            entries,
            control: None,
            pull: [0.0; 4],
        }
    }

    /// These maps with room for an active target's supply (0 until the first
    /// [`Self::set_supply`]) and its footprint mask; unchanged for a target whose control is off.
    pub fn with_target(mut self, target: Option<&crate::sim::control::Target>) -> Self {
        if let Some(t) = target.filter(|t| t.enabled) {
            let offset = self.values.len() as u32;
            self.values.extend(std::iter::repeat_n(0.0, t.mask.len()));
            self.values.extend_from_slice(&t.mask);
            self.values.extend(t.field.iter().flatten());
            self.control = Some([
                offset,
                t.grid.n[0] as u32,
                t.grid.n[2] as u32,
                t.grid.n[1] as u32,
            ]);
            self.pull = [
                t.pull as f32,
                t.reach as f32,
                t.threshold as f32,
                t.grid.cell[1] as f32,
            ];
        }
        self
    }

    /// Replaces the supply map; returns its offset in values (None without control or when
    /// `supply` does not have one value per column).
    pub fn set_supply(&mut self, supply: &[f32]) -> Option<usize> {
        let [offset, nx, nz, _] = self.control?;
        let offset = offset as usize;
        if supply.len() != (nx * nz) as usize {
            return None;
        }
        self.values[offset..offset + supply.len()].copy_from_slice(supply);
        Some(offset)
    }

    /// `sources` with each image source's map entry filled in.
    pub fn with_maps(&self, mut sources: [SourceGpu; MAX_SOURCES]) -> [SourceGpu; MAX_SOURCES] {
        for (s, e) in sources.iter_mut().zip(&self.entries) {
            if e[1] > 0 {
                s.kind[1..].copy_from_slice(e);
            }
        }
        sources
    }
}

/// A source as the manifest lists it: what it is, where it acts (its bounds in metres, y up,
/// before any wrap across a periodic face) and when.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SourceRecord {
    pub index: usize,
    pub shape: SourceShape,
    /// `ground` (acts from the floor up to `bounds_max[1]`) or `air`.
    pub placement: String,
    pub bounds_min: [f64; 3],
    pub bounds_max: [f64; 3],
    /// Heating (K/s) and vapor (kg/kg per s) at full strength.
    pub strength: f64,
    pub vapor: f64,
    pub start: f64,
    pub end: Option<f64>,
    pub ramp: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image_sha256: Option<String>,
}

/// Every source of a shot, for the manifest.
pub fn records(cfg: &ShotConfig) -> Vec<SourceRecord> {
    let size = cfg.domain.size;
    cfg.physics
        .sources
        .iter()
        .enumerate()
        .map(|(index, s)| {
            let (lo, hi) = bounds(s, size, cfg.physics.heat_height);
            SourceRecord {
                index,
                shape: s.shape,
                placement: if s.on_ground() { "ground" } else { "air" }.into(),
                bounds_min: lo,
                bounds_max: hi,
                strength: s.strength,
                vapor: s.vapor_rate(),
                start: s.start,
                end: s.end,
                ramp: s.ramp,
                image: s.image.clone(),
                image_sha256: s.image_sha256.clone(),
            }
        })
        .collect()
}

/// Axis-aligned bounds of where a source acts (m): a rotated shape's box holds it whole.
pub fn bounds(s: &HeatSource, size: [f64; 3], heat_height: f64) -> ([f64; 3], [f64; 3]) {
    let c = |i: usize| s.center.get(i).copied().unwrap_or(0.0);
    let top = s.height.unwrap_or(heat_height);
    let a = s.angle.unwrap_or(0.0).to_radians();
    // half extents of a rectangle (hx, hz) rotated by a
    let rotated = |hx: f64, hz: f64| {
        (
            (hx * a.cos()).abs() + (hz * a.sin()).abs(),
            (hx * a.sin()).abs() + (hz * a.cos()).abs(),
        )
    };
    let half = |i: usize| {
        s.size
            .as_ref()
            .and_then(|v| v.get(i))
            .map_or(0.0, |x| 0.5 * x)
    };
    match (s.shape, s.center.len()) {
        (SourceShape::Image, _) => ([0.0; 3], [size[0], top, size[2]]),
        (SourceShape::Disc, _) => {
            let r = s.radius.unwrap_or(0.0);
            ([c(0) - r, 0.0, c(1) - r], [c(0) + r, top, c(1) + r])
        }
        (SourceShape::Ellipse, _) => {
            let r = s.radii.unwrap_or([0.0; 2]);
            // the ellipse's extent along x and z after the rotation
            let ex = ((r[0] * a.cos()).powi(2) + (r[1] * a.sin()).powi(2)).sqrt();
            let ez = ((r[0] * a.sin()).powi(2) + (r[1] * a.cos()).powi(2)).sqrt();
            ([c(0) - ex, 0.0, c(1) - ez], [c(0) + ex, top, c(1) + ez])
        }
        (SourceShape::Sphere, _) => {
            let r = s.radius.unwrap_or(0.0);
            (
                [c(0) - r, c(1) - r, c(2) - r],
                [c(0) + r, c(1) + r, c(2) + r],
            )
        }
        (SourceShape::Box, 3) => {
            let (ex, ez) = rotated(half(0), half(2));
            (
                [c(0) - ex, c(1) - half(1), c(2) - ez],
                [c(0) + ex, c(1) + half(1), c(2) + ez],
            )
        }
        (SourceShape::Box, _) => {
            let (ex, ez) = rotated(half(0), half(1));
            ([c(0) - ex, 0.0, c(1) - ez], [c(0) + ex, top, c(1) + ez])
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shot(sources: &str) -> ShotConfig {
        crate::shot::load_str(
            &format!(
                "shot: t\noutput: {{frames: {{start: 1, end: 2}}}}\n\
                 domain: {{size: [1000, 800, 1000], spacing: 50}}\nphysics: {{sources: {sources}}}\n"
            ),
            "t.yaml",
            &[],
        )
        .unwrap().into_config()
    }

    #[test]
    fn packing_and_bounds_of_each_shape() {
        let cfg = shot(
            "[{shape: ellipse, center: [500, 500], radii: [200, 100], angle: 90, strength: 0.1},\
              {shape: box, center: [300, 200, 700], size: [100, 60, 40], angle: 90, strength: 0.2, start: 10, ramp: 10},\
              {shape: box, center: [300, 700], size: [100, 40], height: 250, vapor: 1.0e-5}]",
        );
        let p = pack(&cfg, 2.0, 14.0);
        assert_eq!(p[0].kind[0], KIND_ELLIPSE);
        assert_eq!(p[0].center, [500.0, 0.0, 500.0, 100.0]);
        assert_eq!(&p[0].extent[..2], &[200.0, 100.0]);
        assert!(p[0].rate[0].abs() < 1e-7 && (p[0].rate[1] - 1.0).abs() < 1e-7);
        assert_eq!(p[1].kind[0], KIND_AIR_BOX);
        assert_eq!(p[1].center[..3], [300.0, 200.0, 700.0]);
        assert_eq!(&p[1].extent[..3], &[50.0, 30.0, 20.0]);
        // the schedule at the substep's midpoint, 15 s: halfway up the 10 s ramp
        assert!((p[1].rate[2] - 0.1).abs() < 1e-7, "{:?}", p[1].rate);
        assert_eq!(p[2].kind[0], KIND_GROUND_BOX);
        assert_eq!(p[2].center[3], 250.0);
        assert_eq!(p[2].rate[2..], [0.0, 1e-5]);
        assert_eq!(p[3], SourceGpu::default());
        // bounds: the ellipse turned by 90 degrees spans 100 m along x and 200 m along z
        let s = &cfg.physics.sources;
        let (lo, hi) = bounds(&s[0], cfg.domain.size, 100.0);
        let near = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9);
        assert!(
            near(lo, [400.0, 0.0, 300.0]) && near(hi, [600.0, 100.0, 700.0]),
            "{lo:?} {hi:?}"
        );
        let (lo, hi) = bounds(&s[1], cfg.domain.size, 100.0);
        assert!(
            near(lo, [280.0, 170.0, 650.0]) && near(hi, [320.0, 230.0, 750.0]),
            "{lo:?} {hi:?}"
        );
        let r = records(&cfg);
        assert_eq!(r[2].placement, "ground");
        assert_eq!(r[2].bounds_max[1], 250.0);
        assert_eq!(r[1].placement, "air");
    }
}
