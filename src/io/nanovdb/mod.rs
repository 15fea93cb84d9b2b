//! NanoVDB files (`.nvdb`), the layout of NanoVDB 32.4 (OpenVDB 10's NanoVDB, what Debian 12's
//! `libnanovdb-tools` read and validate): the writer (`write.rs`) and a reader for `nimbus
//! inspect` and the tests (`read.rs`). Both follow `nanovdb/NanoVDB.h`, `util/IO.h`,
//! `util/GridStats.h`, `util/GridChecksum.h` and `util/OpenToNanoVDB.h` of that version; the
//! byte offsets are in `layout.rs`.
//!
//! A file holds one segment per grid, as `nanovdb_convert` writes it: a 16-byte header, the
//! grid's 176-byte record and name, then its buffer uncompressed (codec NONE), so a GPU renderer
//! can map it as it is. A grid's
//! buffer is `GridData | TreeData | RootData + tiles | upper nodes | lower nodes | leaves`, every
//! part 32-byte aligned, nodes breadth first in OpenVDB's order (`nanovdb_convert`'s layout).
//! Statistics are NanoVDB's "all" mode (bounding boxes, min/max, average and standard deviation
//! per node) and the checksum its "full" mode (a CRC32 of the grid, tree and root, and a CRC32 of
//! every node's CRC32), which `nanovdb_validate` checks. For the same grid, the file is byte for
//! byte what `nanovdb_convert -c full` (with `--fp4`, `--fp8`, `--fp16`, `--fpN -a TOL`) writes
//! from nimbus's VDB file (tests/export_nanovdb.rs).
pub mod layout;
pub mod read;
pub mod write;

pub use read::{read_bytes, read_file, Leaves, NanoFileGrid};
pub use write::{encode, write_file, NanoGrid, NanoValues};

/// "NanoVDB0", little endian.
pub const MAGIC: u64 = 0x3042_4456_6f6e_614e;
/// Version 32.4.2 packed as NanoVDB does (11 + 11 + 10 bits).
pub const VERSION: u32 = (32 << 21) | (4 << 10) | 2;
/// Longest grid name stored in the grid itself (255 bytes and a NUL); nimbus writes no longer
/// (a limit the config checks, so it is the config's).
pub const MAX_NAME_BYTES: usize = crate::config::MAX_NANOVDB_NAME_BYTES;

/// How a float grid's values are stored: as they are, or quantised per leaf into codes between
/// the leaf's minimum and maximum (NanoVDB's Fp4, Fp8, Fp16, and FpN with a bit width per leaf).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Quantise {
    Float,
    Fp4,
    Fp8,
    Fp16,
    /// Fewest bits (1, 2, 4, 8, else 16) per leaf that keep every value within `tolerance`.
    FpN {
        tolerance: f32,
    },
}

/// NanoVDB's `GridType` values nimbus writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum GridType {
    Float = 1,
    Vec3f = 6,
    Fp4 = 13,
    Fp8 = 14,
    Fp16 = 15,
    FpN = 16,
}

impl GridType {
    pub fn from_u32(v: u32) -> Option<Self> {
        Some(match v {
            1 => GridType::Float,
            6 => GridType::Vec3f,
            13 => GridType::Fp4,
            14 => GridType::Fp8,
            15 => GridType::Fp16,
            16 => GridType::FpN,
            _ => return None,
        })
    }
    /// NanoVDB's `toStr(GridType)` (what `nanovdb_print` shows).
    pub fn name(self) -> &'static str {
        match self {
            GridType::Float => "float",
            GridType::Vec3f => "Vec3f",
            GridType::Fp4 => "Float4",
            GridType::Fp8 => "Float8",
            GridType::Fp16 => "Float16",
            GridType::FpN => "FloatN",
        }
    }
}

/// NanoVDB's `GridClass` values nimbus writes (OpenVDB's class, as `nanovdb_convert` maps it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum GridClass {
    Unknown = 0,
    FogVolume = 2,
}

impl GridClass {
    /// From an OpenVDB class name (`io::vdb::CLASS_*`).
    pub fn from_openvdb(class: &str) -> Self {
        if class == crate::io::vdb::CLASS_FOG_VOLUME {
            GridClass::FogVolume
        } else {
            GridClass::Unknown
        }
    }
}

/// NanoVDB's `io::stringHash` of a grid name (the file records it beside the name).
pub fn string_hash(s: &str) -> u64 {
    let mut hash: u64 = 0;
    for &c in s.as_bytes() {
        if c == 0 {
            break;
        }
        let overflow = hash >> 56;
        hash = hash.wrapping_mul(67).wrapping_add(c as u64 + overflow);
    }
    hash
}

#[cfg(test)]
mod tests;
