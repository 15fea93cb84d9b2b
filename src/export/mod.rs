//! The frame the VDB files are written in, as the renderer wants it: scene scale (metres per
//! unit), up axis and the velocity's time basis, resolved from `export.*` and the renderer
//! profile. The simulation, the splat, the EXR atlas and the previews stay in nimbus's own frame
//! (metres, y-up, m/s of simulated time); `ExportSpace` maps splat grids into the export frame
//! exactly (an index permutation, no resampling) and back.
pub mod optics;
pub mod profile;
pub mod usd;

use crate::config::{ExportConfig, NanoPrecision, ShotConfig, UpAxis, VectorClass, VelocityTime};
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_DIM, LEAF_VOXELS};
use crate::io::vdb::{MetaValue, CLASS_FOG_VOLUME, CLASS_UNKNOWN};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The resolved export conventions of a shot; one for the whole shot, so the transform is too.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportSpace {
    /// `none` or the renderer profile.
    pub profile: String,
    /// Metres per scene unit.
    pub scale: f64,
    pub up_axis: UpAxis,
    pub velocity_time: VelocityTime,
    /// What one unit of the velocity grid is, in words (also in the grid's metadata).
    pub velocity_unit: String,
    pub velocity_class: VectorClass,
    /// Simulated seconds per frame and playback frames per second.
    pub frame_seconds: f64,
    pub fps: f64,
    /// The density grid's physical unit and extinction (`export.optics`); absent in manifests
    /// written before it existed.
    #[serde(default)]
    pub optics: Option<optics::Optics>,
}

impl ExportSpace {
    pub fn from_config(cfg: &ShotConfig) -> Self {
        let e = &cfg.export;
        let d = profile::defaults(e.profile);
        let velocity_time = e.velocity_time.unwrap_or(d.velocity_time);
        Self {
            profile: profile::name(e.profile).into(),
            scale: e.scale,
            up_axis: e.up_axis.unwrap_or(d.up_axis),
            velocity_time,
            velocity_unit: velocity_unit(velocity_time).into(),
            velocity_class: e.grids.velocity_class.unwrap_or(d.velocity_class),
            frame_seconds: cfg.output.frame_seconds,
            fps: cfg.output.fps,
            optics: Some(optics::Optics::from_config(cfg)),
        }
    }

    /// Grid aliases: the configured ones plus the profile's, where they name a written grid and
    /// clash with nothing configured.
    pub fn aliases(cfg: &ShotConfig) -> BTreeMap<String, String> {
        aliases_of(&cfg.export)
    }

    /// Factor from simulated m/s to the velocity grid's unit (before the scale).
    pub fn time_factor(&self) -> f64 {
        match self.velocity_time {
            VelocityTime::Playback => self.frame_seconds * self.fps,
            VelocityTime::Simulated => 1.0,
            VelocityTime::PerFrame => self.frame_seconds,
        }
    }

    /// OpenVDB class name of the velocity grid.
    pub fn velocity_class_name(&self) -> &'static str {
        match self.velocity_class {
            VectorClass::Unknown => CLASS_UNKNOWN,
            VectorClass::FogVolume => CLASS_FOG_VOLUME,
        }
    }

    /// A direction (or velocity) from nimbus's frame into the export axes (no scaling).
    pub fn rotate(&self, v: [f64; 3]) -> [f64; 3] {
        match self.up_axis {
            UpAxis::Y => v,
            // +90 degrees about x: +y (up) onto +z, +z onto -y; right-handed both sides.
            UpAxis::Z => [v[0], -v[2], v[1]],
        }
    }

    /// A point in metres, nimbus frame, to scene units in the export frame.
    pub fn point(&self, p: [f64; 3]) -> [f64; 3] {
        self.rotate(p).map(|x| x / self.scale)
    }

    /// A simulated velocity (m/s) to the velocity grid's unit and axes.
    pub fn velocity(&self, v: [f64; 3]) -> [f64; 3] {
        let k = self.time_factor() / self.scale;
        self.rotate(v).map(|x| x * k)
    }

    /// The inverse of `rotate`.
    pub fn rotate_to_sim(&self, v: [f64; 3]) -> [f64; 3] {
        match self.up_axis {
            UpAxis::Y => v,
            UpAxis::Z => [v[0], v[2], -v[1]],
        }
    }

    /// The inverse of `point`.
    pub fn point_to_sim(&self, p: [f64; 3]) -> [f64; 3] {
        self.rotate_to_sim(p).map(|x| x * self.scale)
    }

    /// The inverse of `velocity`.
    pub fn velocity_to_sim(&self, v: [f64; 3]) -> [f64; 3] {
        let k = self.scale / self.time_factor();
        self.rotate_to_sim(v).map(|x| x * k)
    }

    /// The transform of the exported grids for the splat's transform `t`.
    pub fn transform(&self, t: &GridTransform) -> GridTransform {
        let v = t.voxel_size;
        let o = t.origin;
        let origin = match self.up_axis {
            UpAxis::Y => o,
            // Index (i, j, k) goes to (i, -1 - k, j) so leaves stay 8-aligned; the centre of
            // voxel (i, -1 - k, j) must be the rotated centre of (i, j, k): (x, -z, y).
            UpAxis::Z => [o[0], v - o[2], o[1]],
        };
        GridTransform {
            voxel_size: v / self.scale,
            origin: origin.map(|x| x / self.scale),
        }
    }

    /// A scalar grid in the export frame (values unchanged).
    pub fn float_grid(&self, g: SparseGrid<f32>) -> SparseGrid<f32> {
        self.remap(g, |x| x)
    }

    /// The velocity grid in the export frame and time basis.
    pub fn velocity_grid(&self, g: SparseGrid<[f32; 3]>) -> SparseGrid<[f32; 3]> {
        let k = self.time_factor() / self.scale;
        let up = self.up_axis;
        self.remap(g, move |u| {
            let u = u.map(|x| x as f64 * k);
            let r = match up {
                UpAxis::Y => u,
                UpAxis::Z => [u[0], -u[2], u[1]],
            };
            r.map(|x| x as f32)
        })
    }

    /// A grid of positions (the rest grids) in the export frame: each value mapped like a point.
    pub fn point_grid(&self, g: SparseGrid<[f32; 3]>) -> SparseGrid<[f32; 3]> {
        let s = self.clone();
        self.remap(g, move |p| s.point(p.map(|x| x as f64)).map(|x| x as f32))
    }

    /// A scalar grid read back from an export, in nimbus's frame again (the inverse of
    /// `float_grid` up to the transform's rounding).
    pub fn float_grid_to_sim(&self, g: SparseGrid<f32>) -> SparseGrid<f32> {
        let t = g.transform;
        let v = t.voxel_size * self.scale;
        let o = t.origin.map(|x| x * self.scale);
        let (leaves, origin) = match self.up_axis {
            UpAxis::Y => (g.leaves, o),
            UpAxis::Z => (
                permute_leaves(g.leaves, |[x, y, z]| [x, z, -1 - y], |x| x),
                [o[0], o[2], v - o[1]],
            ),
        };
        SparseGrid {
            name: g.name,
            background: g.background,
            transform: GridTransform {
                voxel_size: v,
                origin,
            },
            leaves,
        }
    }

    fn remap<T: Copy + Default>(&self, g: SparseGrid<T>, value: impl Fn(T) -> T) -> SparseGrid<T> {
        let transform = self.transform(&g.transform);
        let leaves = match self.up_axis {
            UpAxis::Y => g
                .leaves
                .into_iter()
                .map(|mut l| {
                    for x in l.values.iter_mut() {
                        *x = value(*x);
                    }
                    l
                })
                .collect(),
            UpAxis::Z => permute_leaves(g.leaves, |[x, y, z]| [x, -1 - z, y], value),
        };
        SparseGrid {
            name: g.name,
            background: g.background,
            transform,
            leaves,
        }
    }

    /// Metadata of the velocity grid: its time basis, unit and scene scale.
    pub fn velocity_metadata(&self) -> Vec<(String, MetaValue)> {
        vec![
            (
                "nimbus_velocity_time".into(),
                MetaValue::String(velocity_time_name(self.velocity_time).into()),
            ),
            (
                "nimbus_velocity_unit".into(),
                MetaValue::String(self.velocity_unit.clone()),
            ),
            ("nimbus_fps".into(), MetaValue::Double(self.fps)),
            (
                "nimbus_frame_seconds".into(),
                MetaValue::Double(self.frame_seconds),
            ),
        ]
    }

    /// File metadata: scene scale, axis and profile (lengths are in scene units).
    pub fn file_metadata(&self, voxel_size_m: f64) -> Vec<(String, MetaValue)> {
        vec![
            (
                "nimbus_profile".into(),
                MetaValue::String(self.profile.clone()),
            ),
            (
                "nimbus_metres_per_unit".into(),
                MetaValue::Double(self.scale),
            ),
            (
                "nimbus_up_axis".into(),
                MetaValue::String(
                    match self.up_axis {
                        UpAxis::Y => "y",
                        UpAxis::Z => "z",
                    }
                    .into(),
                ),
            ),
            (
                "nimbus_voxel_size".into(),
                MetaValue::Double(voxel_size_m / self.scale),
            ),
        ]
    }
}

/// Grid aliases of an export config: the configured ones plus the profile's, where they name
/// a written grid and clash with nothing configured.
pub fn aliases_of(e: &ExportConfig) -> BTreeMap<String, String> {
    let g = &e.grids;
    let mut out = g.aliases.clone();
    let names = [&g.density, &g.temperature, &g.vapor, &g.velocity];
    for (alias, key) in profile::defaults(e.profile).aliases {
        let target = match *key {
            "density" => &g.density,
            "temperature" => &g.temperature,
            "vapor" => &g.vapor,
            _ => &g.velocity,
        };
        let clash = names.iter().any(|n| n.as_str() == *alias) || out.contains_key(*alias);
        if !target.is_empty() && !clash {
            out.insert(alias.to_string(), target.clone());
        }
    }
    out
}

/// What a grid of the VDB files holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GridKind {
    /// density, temperature, vapor: float fog volumes.
    Scalar,
    /// The velocity (vec3).
    Velocity,
    /// A rest-position grid (vec3, points).
    Rest,
}

/// A grid of the VDB files, in file order: a grid, then its aliases (OpenVDB instances of it).
#[derive(Debug, Clone, PartialEq)]
pub struct VdbGridName {
    pub name: String,
    pub kind: GridKind,
    /// For an alias: the grid it names again.
    pub alias_of: Option<String>,
}

impl VdbGridName {
    /// A vec3 grid (velocity, rest).
    pub fn vector(&self) -> bool {
        self.kind != GridKind::Scalar
    }
}

/// Every grid name the VDB files of `e` hold (what the writer writes, whatever the frame).
pub fn vdb_grid_names(e: &ExportConfig) -> Vec<VdbGridName> {
    let g = &e.grids;
    let rest2 = format!("{}2", g.rest);
    let dual = !g.rest.is_empty() && e.detail.rest_period > 0;
    let grids = [
        (g.density.as_str(), GridKind::Scalar),
        (g.temperature.as_str(), GridKind::Scalar),
        (g.vapor.as_str(), GridKind::Scalar),
        (g.velocity.as_str(), GridKind::Velocity),
        (g.rest.as_str(), GridKind::Rest),
        (if dual { rest2.as_str() } else { "" }, GridKind::Rest),
    ];
    let aliases = aliases_of(e);
    let mut out = Vec::new();
    for (name, kind) in grids.into_iter().filter(|(n, _)| !n.is_empty()) {
        out.push(VdbGridName {
            name: name.to_string(),
            kind,
            alias_of: None,
        });
        for (alias, target) in &aliases {
            if target == name {
                out.push(VdbGridName {
                    name: alias.clone(),
                    kind,
                    alias_of: Some(name.to_string()),
                });
            }
        }
    }
    out
}

/// The grids `export.nanovdb` writes, in VDB file order, each with its precision (vector grids:
/// `float`, which validation makes sure of).
pub fn nanovdb_grids(e: &ExportConfig) -> Vec<(VdbGridName, NanoPrecision)> {
    let n = &e.nanovdb;
    vdb_grid_names(e)
        .into_iter()
        .filter_map(|g| {
            if n.grids.0.is_empty() {
                return Some((g, n.precision));
            }
            let own = n.grids.0.iter().find(|(name, _)| *name == g.name)?.1;
            Some((g, own.unwrap_or(n.precision)))
        })
        .collect()
}

pub fn velocity_time_name(t: VelocityTime) -> &'static str {
    match t {
        VelocityTime::Playback => "playback",
        VelocityTime::Simulated => "simulated",
        VelocityTime::PerFrame => "per_frame",
    }
}

fn velocity_unit(t: VelocityTime) -> &'static str {
    match t {
        VelocityTime::Playback => "scene units per second of playback",
        VelocityTime::Simulated => "scene units per second of simulated time",
        VelocityTime::PerFrame => "scene units per frame",
    }
}

/// Moves every voxel to `index(ijk)` (a signed axis permutation that maps 8-aligned leaves onto
/// 8-aligned leaves) and its value through `value`; leaves are re-sorted by origin.
fn permute_leaves<T: Copy + Default>(
    leaves: Vec<Leaf<T>>,
    index: impl Fn([i32; 3]) -> [i32; 3],
    value: impl Fn(T) -> T,
) -> Vec<Leaf<T>> {
    let mut out: Vec<Leaf<T>> = leaves
        .into_iter()
        .map(|l| {
            // The leaf's new origin is the image of whichever corner lands lowest.
            let far = l.origin.map(|o| o + LEAF_DIM - 1);
            let a = index(l.origin);
            let b = index(far);
            let origin = [0, 1, 2].map(|k| a[k].min(b[k]));
            let mut values = Box::new([T::default(); LEAF_VOXELS]);
            let mut mask = [0u64; 8];
            for n in 0..LEAF_VOXELS {
                let local = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
                let ijk = [0, 1, 2].map(|k| l.origin[k] + local[k]);
                let t = index(ijk);
                let m = Leaf::<T>::offset(t[0], t[1], t[2]);
                values[m] = if l.is_active(n) {
                    value(l.values[n])
                } else {
                    l.values[n]
                };
                if l.is_active(n) {
                    mask[m / 64] |= 1 << (m % 64);
                }
            }
            debug_assert!(origin.iter().all(|o| o % LEAF_DIM == 0));
            Leaf {
                origin,
                values,
                mask,
            }
        })
        .collect();
    out.sort_by_key(|l| l.origin);
    out
}

#[cfg(test)]
mod tests;
