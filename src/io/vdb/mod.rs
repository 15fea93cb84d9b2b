//! OpenVDB files (format 224, as OpenVDB 10 writes them): the writer, a reader for float and
//! vec3s grids of formats 222-225 (tiles included), and [`volume::Volume`], a float grid read
//! back as a function of index space (the VDB targets of `control.target.vdb`). Layout notes:
//! `docs/ARCHITECTURE.md` and the comments in `write.rs` and `read.rs`.
pub mod blosc;
pub mod read;
pub mod volume;
pub mod write;

pub use crate::config::Compression;
pub use read::{read_bytes, read_file};
pub use write::{encode, write_file};

use crate::ground::SparseGrid;

/// File format version written (OpenVDB 10; readers before OpenVDB 13 reject 225).
pub const FILE_VERSION: u32 = 224;
/// Library version recorded in the header.
pub const LIBRARY_VERSION: (u32, u32) = (10, 0);
pub const MAGIC: i64 = 0x5644_4220;
/// OpenVDB `GridBase::gridClassToString` names.
pub const CLASS_FOG_VOLUME: &str = "fog volume";
pub const CLASS_LEVEL_SET: &str = "level set";
pub const CLASS_UNKNOWN: &str = "unknown";

/// Stream compression flags (OpenVDB `io::COMPRESS_*`).
pub const COMPRESS_ZIP: u32 = 0x1;
pub const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub const COMPRESS_BLOSC: u32 = 0x4;

/// One grid of a file. `name` is the grid name in the file; `aliases` are extra names for the
/// same grid (e.g. `heat` for Blender), written as OpenVDB instances of it (metadata and
/// transform only, sharing the tree).
#[derive(Debug, Clone)]
pub struct VdbGrid {
    pub name: String,
    pub aliases: Vec<String>,
    pub data: GridData,
    /// OpenVDB grid class (`class` metadata): "fog volume" for float grids, "unknown" for
    /// vector grids unless set.
    pub class: &'static str,
    /// Extra grid metadata (e.g. the velocity's time basis), written on the grid and its aliases.
    pub metadata: Vec<(String, MetaValue)>,
}

#[derive(Debug, Clone)]
pub enum GridData {
    /// `Tree_float_5_4_3`, class fog volume.
    Float(SparseGrid<f32>),
    /// `Tree_vec3s_5_4_3` (velocity), vector type contravariant relative.
    Vec3(SparseGrid<[f32; 3]>),
}

impl VdbGrid {
    pub fn float(name: impl Into<String>, grid: SparseGrid<f32>) -> Self {
        VdbGrid {
            name: name.into(),
            aliases: Vec::new(),
            data: GridData::Float(grid),
            class: CLASS_FOG_VOLUME,
            metadata: Vec::new(),
        }
    }
    pub fn vec3(name: impl Into<String>, grid: SparseGrid<[f32; 3]>) -> Self {
        VdbGrid {
            name: name.into(),
            aliases: Vec::new(),
            data: GridData::Vec3(grid),
            class: CLASS_UNKNOWN,
            metadata: Vec::new(),
        }
    }
    pub fn with_class(mut self, class: &'static str) -> Self {
        self.class = class;
        self
    }
    pub fn with_alias(mut self, alias: impl Into<String>) -> Self {
        self.aliases.push(alias.into());
        self
    }
    pub fn active_voxel_count(&self) -> u64 {
        match &self.data {
            GridData::Float(g) => g.active_voxel_count(),
            GridData::Vec3(g) => g.active_voxel_count(),
        }
    }
}

/// A typed metadata value (the OpenVDB metadata types nimbus uses).
#[derive(Debug, Clone, PartialEq)]
pub enum MetaValue {
    String(String),
    Int32(i32),
    Int64(i64),
    Float(f32),
    Double(f64),
    Bool(bool),
    Vec3i([i32; 3]),
    Vec3d([f64; 3]),
}

impl MetaValue {
    pub fn type_name(&self) -> &'static str {
        match self {
            MetaValue::String(_) => "string",
            MetaValue::Int32(_) => "int32",
            MetaValue::Int64(_) => "int64",
            MetaValue::Float(_) => "float",
            MetaValue::Double(_) => "double",
            MetaValue::Bool(_) => "bool",
            MetaValue::Vec3i(_) => "vec3i",
            MetaValue::Vec3d(_) => "vec3d",
        }
    }
}

impl std::fmt::Display for MetaValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MetaValue::String(s) => write!(f, "{s}"),
            MetaValue::Int32(v) => write!(f, "{v}"),
            MetaValue::Int64(v) => write!(f, "{v}"),
            MetaValue::Float(v) => write!(f, "{v}"),
            MetaValue::Double(v) => write!(f, "{v}"),
            MetaValue::Bool(v) => write!(f, "{v}"),
            MetaValue::Vec3i(v) => write!(f, "{v:?}"),
            MetaValue::Vec3d(v) => write!(f, "{v:?}"),
        }
    }
}

/// A whole file: grids in order, and file-level metadata (written sorted by name, as OpenVDB's
/// `MetaMap` does; a later duplicate name replaces an earlier one).
#[derive(Debug, Clone, Default)]
pub struct VdbFile {
    pub grids: Vec<VdbGrid>,
    pub metadata: Vec<(String, MetaValue)>,
}

impl VdbFile {
    /// File metadata nimbus always writes: creator with version, and the frame number.
    pub fn standard_metadata(frame: i64) -> Vec<(String, MetaValue)> {
        vec![
            (
                "creator".into(),
                MetaValue::String(format!("nimbus {}", crate::VERSION)),
            ),
            ("frame".into(), MetaValue::Int64(frame)),
        ]
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VdbOptions {
    pub compression: Compression,
    /// Store values as 16-bit floats (type name suffix `_HalfFloat`).
    pub half: bool,
}

impl Default for VdbOptions {
    fn default() -> Self {
        VdbOptions {
            compression: Compression::Blosc,
            half: false,
        }
    }
}
