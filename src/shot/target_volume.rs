//! VDB targets (`control.target.vdb`): which float grid of the file is the target, which of its
//! values are inside, and the target's voxels on the controller's grid.
//!
//! Inside: for a grid of class "level set", where the value is below `iso` (default 0: the
//! signed distance is negative; the inactive voxels and tiles inside the narrow band carry the
//! sign, -background); for any other class (fog volumes, densities), where it is above `iso`
//! (default 0.01). The grid's world coordinates (its transform) are placed as a mesh's are:
//! scaled, turned about y, translated. A controller voxel is inside when the grid's value,
//! interpolated trilinearly at the voxel's centre mapped back through the placement and the
//! grid's transform (OpenVDB's box sampler), is inside: the same rule as a mesh's (the centre
//! is inside), so from the voxels on the controller is the same for both.
use super::target::place_point;
use crate::config::TargetConfig;
use crate::ground::VoxelGrid;
use crate::io::vdb::read::ReadFile;
use crate::io::vdb::volume::Volume;
use crate::io::vdb::{GridData, CLASS_FOG_VOLUME, CLASS_LEVEL_SET};
use std::path::Path;

/// Largest VDB file read (bytes; the SHA-256 pin reads files up to this size).
pub const MAX_BYTES: u64 = crate::io::heat_map::MAX_BYTES;
/// Default `iso` of a fog volume (or any grid that is not a level set): inside above it.
pub const FOG_ISO: f64 = 0.01;
/// Default `iso` of a level set: inside below it.
pub const LEVEL_SET_ISO: f64 = 0.0;

/// A VDB target's grid, ready to sample.
#[derive(Debug, Clone)]
pub struct VdbTarget {
    pub volume: Volume,
    /// The grid used and its class.
    pub grid: String,
    pub level_set: bool,
    pub iso: f64,
}

/// Why a VDB target is refused, with the keys it concerns (the first one present in the config
/// file is the one reported).
#[derive(Debug, Clone, PartialEq)]
pub struct VdbError {
    pub keys: &'static [&'static str],
    pub msg: String,
}

const FILE_KEYS: &[&str] = &["control.target.vdb"];
const GRID_KEYS: &[&str] = &["control.target.grid", "control.target.vdb"];
const ISO_KEYS: &[&str] = &[
    "control.target.iso",
    "control.target.grid",
    "control.target.vdb",
];

fn file_err(msg: String) -> VdbError {
    VdbError {
        keys: FILE_KEYS,
        msg,
    }
}

/// Reads `control.target.vdb`, checks its SHA-256 pin and picks its grid; `None` when the
/// target is a mesh.
pub fn load(t: &TargetConfig) -> Option<Result<VdbTarget, VdbError>> {
    let path = t.vdb.as_deref()?;
    Some(load_path(t, path))
}

fn load_path(t: &TargetConfig, path: &str) -> Result<VdbTarget, VdbError> {
    let p = Path::new(path);
    let meta = std::fs::metadata(p).map_err(|e| {
        file_err(match e.kind() {
            std::io::ErrorKind::NotFound => format!("{path}: cannot read the VDB: no such file"),
            _ => format!("{path}: cannot read the VDB: {e}"),
        })
    })?;
    if !meta.is_file() {
        return Err(file_err(format!(
            "{path}: cannot read the VDB: not a regular file"
        )));
    }
    if meta.len() > MAX_BYTES {
        return Err(file_err(format!(
            "{path}: the VDB has {} bytes; at most {MAX_BYTES} are read",
            meta.len()
        )));
    }
    let bytes =
        std::fs::read(p).map_err(|e| file_err(format!("{path}: cannot read the VDB: {e}")))?;
    if let Some(sha) = &t.vdb_sha256 {
        let now = crate::io::heat_map::file_sha256(p).map_err(file_err)?;
        if *sha != now {
            return Err(file_err(format!(
                "{path} has changed since this config was resolved (SHA-256 {now}, recorded {sha}); restore the VDB or start a new run"
            )));
        }
    }
    let file = crate::io::vdb::read_bytes(&bytes).map_err(|e| file_err(format!("{path}: {e}")))?;
    let g = pick_grid(&file, t.grid.as_deref(), path)?;
    let volume = Volume::new(g).expect("pick_grid returns float grids");
    let level_set = g.class() == CLASS_LEVEL_SET;
    let iso = t
        .iso
        .unwrap_or(if level_set { LEVEL_SET_ISO } else { FOG_ISO });
    let target = VdbTarget {
        volume,
        grid: g.name.clone(),
        level_set,
        iso,
    };
    let rule = target.rule();
    if target.is_inside(target.volume.background as f64) {
        return Err(VdbError {
            keys: ISO_KEYS,
            msg: format!(
                "{path}: grid '{}' has background {}, which is inside ({rule}): the target would fill all space",
                g.name, target.volume.background
            ),
        });
    }
    if target.index_bounds().is_none() {
        return Err(VdbError {
            keys: ISO_KEYS,
            msg: format!("{path}: grid '{}' holds no value inside ({rule})", g.name),
        });
    }
    Ok(target)
}

/// One grid's description for messages: `name (type, class)`.
fn describe(file: &ReadFile) -> String {
    let mut all: Vec<String> = file
        .grids
        .iter()
        .map(|g| format!("{} ({}, {})", g.name, g.type_name, g.class()))
        .collect();
    all.extend(file.skipped.iter().map(|(n, ty)| format!("{n} ({ty})")));
    if all.is_empty() {
        "none".into()
    } else {
        all.join(", ")
    }
}

fn is_float(g: &crate::io::vdb::read::ReadGrid) -> bool {
    matches!(g.data, GridData::Float(_))
}

/// The grid named `want`, or by default the first float grid of class fog volume or level set,
/// else the float grid named `density`, else the only float grid.
fn pick_grid<'a>(
    file: &'a ReadFile,
    want: Option<&str>,
    path: &str,
) -> Result<&'a crate::io::vdb::read::ReadGrid, VdbError> {
    let usable = "a target is a float grid (Tree_float_5_4_3: a fog volume or a level set; double grids are not read)";
    if let Some(name) = want {
        return match file.grids.iter().find(|g| g.name == name) {
            Some(g) if is_float(g) => Ok(g),
            Some(g) => Err(VdbError {
                keys: GRID_KEYS,
                msg: format!("{path}: grid '{name}' is a {}; {usable}", g.type_name),
            }),
            None => Err(VdbError {
                keys: GRID_KEYS,
                msg: match file.skipped.iter().find(|(n, _)| n == name) {
                    Some((_, ty)) => format!("{path}: grid '{name}' is a {ty}; {usable}"),
                    None => format!("{path}: no grid '{name}' (grids: {})", describe(file)),
                },
            }),
        };
    }
    let floats: Vec<_> = file.grids.iter().filter(|g| is_float(g)).collect();
    if let Some(g) = floats
        .iter()
        .find(|g| matches!(g.class().as_str(), CLASS_FOG_VOLUME | CLASS_LEVEL_SET))
        .or_else(|| floats.iter().find(|g| g.name == "density"))
    {
        return Ok(g);
    }
    match floats.as_slice() {
        [g] => Ok(g),
        [] => Err(file_err(format!(
            "{path}: no usable grid (grids: {}); {usable}",
            describe(file)
        ))),
        _ => Err(VdbError {
            keys: GRID_KEYS,
            msg: format!(
                "{path}: {} float grids, none a fog volume or level set nor named density (grids: {}); name one with control.target.grid",
                floats.len(),
                describe(file)
            ),
        }),
    }
}

impl VdbTarget {
    pub fn is_inside(&self, v: f64) -> bool {
        if self.level_set {
            v < self.iso
        } else {
            v > self.iso
        }
    }

    /// The inside rule in words, for messages.
    pub fn rule(&self) -> String {
        let class = if self.level_set {
            "level set: inside where the value is below iso"
        } else {
            "not a level set: inside where the value is above iso"
        };
        format!("{class} {}", crate::config::fmt_float(self.iso))
    }

    /// First and last index of the voxels whose value is inside.
    fn index_bounds(&self) -> Option<([i64; 3], [i64; 3])> {
        self.volume.bounds(|v| self.is_inside(v as f64))
    }

    /// The box (m, in the domain) the placed target's inside voxels span, each voxel a cube of
    /// one voxel edge around its centre.
    pub fn placed_bounds(&self, t: &TargetConfig) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.index_bounds().unwrap_or(([0; 3], [0; 3]));
        self.placed_box(t, lo.map(|c| c as f64 - 0.5), hi.map(|c| c as f64 + 0.5))
    }

    /// The placed box around the index-space box [lo, hi] (its 8 corners placed).
    fn placed_box(&self, t: &TargetConfig, lo: [f64; 3], hi: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let mut out = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for c in 0..8 {
            let ijk = [0, 1, 2].map(|a| if c >> a & 1 == 1 { hi[a] } else { lo[a] });
            let p = place_point(self.volume.transform.index_to_world(ijk), t);
            out.0 = [0, 1, 2].map(|a| out.0[a].min(p[a]));
            out.1 = [0, 1, 2].map(|a| out.1[a].max(p[a]));
        }
        out
    }

    /// Inside flags of every voxel of `grid` (by its centre; index [`VoxelGrid::index`]).
    /// Only the voxels within one grid voxel of the inside voxels' box are sampled: beyond it
    /// every interpolation corner is outside.
    pub fn voxelize(&self, t: &TargetConfig, grid: &VoxelGrid) -> Vec<bool> {
        let mut inside = vec![false; grid.len()];
        let Some((lo, hi)) = self.index_bounds() else {
            return inside;
        };
        let (plo, phi) = self.placed_box(t, lo.map(|c| c as f64 - 1.0), hi.map(|c| c as f64 + 1.0));
        let range = |a: usize| {
            let first = (plo[a] / grid.cell[a] - 0.5).ceil().max(0.0) as usize;
            let last = ((phi[a] / grid.cell[a] - 0.5).floor().max(-1.0) + 1.0) as usize;
            first..last.min(grid.n[a])
        };
        for j in range(1) {
            for k in range(2) {
                for i in range(0) {
                    let p = [
                        (i as f64 + 0.5) * grid.cell[0],
                        (j as f64 + 0.5) * grid.cell[1],
                        (k as f64 + 0.5) * grid.cell[2],
                    ];
                    let ijk = self.volume.transform.world_to_index(unplace_point(p, t));
                    inside[grid.index(i, j, k)] = self.is_inside(self.volume.sample(ijk));
                }
            }
        }
        inside
    }
}

/// The inverse of [`place_point`].
pub fn unplace_point(p: [f64; 3], t: &TargetConfig) -> [f64; 3] {
    let s = t.scale3();
    let (sin, cos) = t.rotate_y.to_radians().sin_cos();
    let (x, y, z) = (
        p[0] - t.translate[0],
        p[1] - t.translate[1],
        p[2] - t.translate[2],
    );
    [
        (cos * x + sin * z) / s[0],
        y / s[1],
        (-sin * x + cos * z) / s[2],
    ]
}
