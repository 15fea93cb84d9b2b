//! Byte layout of NanoVDB 32.4's structures (`NanoVDB.h`, `util/IO.h`): sizes and field
//! offsets, for the two value types nimbus writes (float: 4 bytes; Vec3f: 12 bytes, statistics
//! as float). Every structure is 32-byte aligned and a multiple of 32 bytes long.

/// `GridData` (672 bytes) fields.
pub mod grid {
    pub const SIZE: usize = 672;
    pub const MAGIC: usize = 0;
    pub const CHECKSUM: usize = 8;
    pub const VERSION: usize = 16;
    pub const FLAGS: usize = 20;
    pub const GRID_INDEX: usize = 24;
    pub const GRID_COUNT: usize = 28;
    pub const GRID_SIZE: usize = 32;
    pub const NAME: usize = 40;
    pub const NAME_SIZE: usize = 256;
    /// `Map`: 9 + 9 + 3 + 1 floats, then 9 + 9 + 3 + 1 doubles.
    pub const MAP: usize = 296;
    pub const WORLD_BBOX: usize = 560;
    pub const VOXEL_SIZE: usize = 608;
    pub const CLASS: usize = 632;
    pub const TYPE: usize = 636;
    pub const BLIND_OFFSET: usize = 640;
    pub const BLIND_COUNT: usize = 648;
}

/// `GridFlags`.
pub mod flags {
    pub const HAS_BBOX: u32 = 1 << 1;
    pub const HAS_MIN_MAX: u32 = 1 << 2;
    pub const HAS_AVERAGE: u32 = 1 << 3;
    pub const HAS_STD_DEVIATION: u32 = 1 << 4;
    pub const IS_BREADTH_FIRST: u32 = 1 << 5;
}

/// `TreeData<3>` (64 bytes): byte offsets from the tree to the first leaf, lower, upper node and
/// the root; node counts (leaf, lower, upper); active tile counts; active voxel count.
pub mod tree {
    pub const SIZE: usize = 64;
    pub const NODE_OFFSET: usize = 0;
    pub const NODE_COUNT: usize = 32;
    pub const TILE_COUNT: usize = 44;
    pub const VOXEL_COUNT: usize = 56;
}

/// The value type of a grid's tree: float (also the upper levels of the quantised types) or
/// Vec3f.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Value {
    Float,
    Vec3f,
}

impl Value {
    /// Bytes of one value.
    pub const fn bytes(self) -> usize {
        match self {
            Value::Float => 4,
            Value::Vec3f => 12,
        }
    }
}

const fn align32(n: usize) -> usize {
    (n + 31) & !31
}

/// `RootData`: bbox (2 x 3 i32), table size (u32), background, min, max (values), average and
/// standard deviation (float); then the tiles.
#[derive(Debug, Clone, Copy)]
pub struct Root {
    pub size: usize,
    pub background: usize,
    pub min: usize,
    pub max: usize,
    pub avg: usize,
    pub dev: usize,
}

pub const ROOT_BBOX: usize = 0;
pub const ROOT_TABLE_SIZE: usize = 24;
/// A root tile: key (u64), child offset from the root (i64), state (u32), value; 32 bytes.
pub const TILE_SIZE: usize = 32;
pub const TILE_KEY: usize = 0;
pub const TILE_CHILD: usize = 8;

pub const fn root(v: Value) -> Root {
    let b = v.bytes();
    let background = 28;
    let min = background + b;
    let max = min + b;
    let avg = max + b;
    let dev = avg + 4;
    Root {
        size: align32(dev + 4),
        background,
        min,
        max,
        avg,
        dev,
    }
}

/// `InternalData` of a node of 2^(3 LOG2DIM) entries: bbox (2 x 3 i32), flags (u64), value mask,
/// child mask, min, max (values), average, standard deviation (float), then the 32-byte aligned
/// table of entries (a value or an i64 child offset from the node, each max(value, 8) bytes
/// rounded to 8).
#[derive(Debug, Clone, Copy)]
pub struct Internal {
    pub log2dim: u32,
    pub size: usize,
    pub value_mask: usize,
    pub child_mask: usize,
    pub min: usize,
    pub max: usize,
    pub avg: usize,
    pub dev: usize,
    pub table: usize,
    pub entry: usize,
}

pub const NODE_BBOX: usize = 0;
pub const NODE_FLAGS: usize = 24;

pub const fn internal(v: Value, log2dim: u32) -> Internal {
    let entries = 1usize << (3 * log2dim);
    let mask_bytes = entries / 8;
    let value_mask = 32;
    let child_mask = value_mask + mask_bytes;
    let min = child_mask + mask_bytes;
    let max = min + v.bytes();
    let avg = max + v.bytes();
    let dev = avg + 4;
    let table = align32(dev + 4);
    let entry = if v.bytes() > 8 { 16 } else { 8 };
    Internal {
        log2dim,
        size: table + entries * entry,
        value_mask,
        child_mask,
        min,
        max,
        avg,
        dev,
        table,
        entry,
    }
}

/// Upper internal nodes: 32^3 entries; lower: 16^3.
pub const fn upper(v: Value) -> Internal {
    internal(v, 5)
}
pub const fn lower(v: Value) -> Internal {
    internal(v, 4)
}

/// Leaf fields shared by every leaf type: the active bbox's minimum (3 i32), its extent minus
/// one per axis (3 u8), flags (u8: bit 1 "has a bbox", bits 5-7 the FpN bit width's log2), the
/// value mask (64 bytes).
pub const LEAF_BBOX_MIN: usize = 0;
pub const LEAF_BBOX_DIF: usize = 12;
pub const LEAF_FLAGS: usize = 15;
pub const LEAF_MASK: usize = 16;

/// `LeafData<float>` / `LeafData<Vec3f>`: min, max (values), average, standard deviation
/// (float), then the 512 values, 32-byte aligned.
#[derive(Debug, Clone, Copy)]
pub struct Leaf {
    pub size: usize,
    pub min: usize,
    pub max: usize,
    pub avg: usize,
    pub dev: usize,
    pub values: usize,
}

pub const fn leaf(v: Value) -> Leaf {
    let min = 80;
    let max = min + v.bytes();
    let avg = max + v.bytes();
    let dev = avg + 4;
    let values = align32(dev + 4);
    Leaf {
        size: values + 512 * v.bytes(),
        min,
        max,
        avg,
        dev,
        values,
    }
}

/// `LeafFnBase` of the quantised leaves (96 bytes): the minimum of all 512 values and the
/// quantum (float), then the active values' min, max, average and standard deviation as u16
/// codes; the codes of the 512 values follow at 96.
pub const FN_MINIMUM: usize = 80;
pub const FN_QUANTUM: usize = 84;
pub const FN_MIN: usize = 88;
pub const FN_MAX: usize = 90;
pub const FN_AVG: usize = 92;
pub const FN_DEV: usize = 94;
pub const FN_CODES: usize = 96;

/// Size of a quantised leaf of `bits` bits per value.
pub const fn fn_leaf_size(bits: usize) -> usize {
    FN_CODES + bits * 64
}

/// The file's segment header: magic (u64), version (u32), grid count (u16), codec (u16).
pub const FILE_HEADER: usize = 16;
/// A grid's record in the file (`io::MetaData`), before its NUL-terminated name.
pub mod meta {
    pub const SIZE: usize = 176;
    pub const GRID_SIZE: usize = 0;
    pub const FILE_SIZE: usize = 8;
    pub const NAME_KEY: usize = 16;
    pub const VOXEL_COUNT: usize = 24;
    pub const TYPE: usize = 32;
    pub const CLASS: usize = 36;
    pub const WORLD_BBOX: usize = 40;
    pub const INDEX_BBOX: usize = 88;
    pub const VOXEL_SIZE: usize = 112;
    pub const NAME_SIZE: usize = 136;
    pub const NODE_COUNT: usize = 140;
    pub const TILE_COUNT: usize = 156;
    pub const CODEC: usize = 168;
    pub const VERSION: usize = 172;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sizes NanoVDB.h's static layout gives (checked against the header's own comments
    /// and `nanovdb_convert`'s files).
    #[test]
    fn sizes_match_nanovdb() {
        assert_eq!(root(Value::Float).size, 64);
        assert_eq!(root(Value::Vec3f).size, 96);
        assert_eq!(upper(Value::Float).size, 270_400);
        assert_eq!(lower(Value::Float).size, 33_856);
        assert_eq!(upper(Value::Vec3f).size, 532_544);
        assert_eq!(lower(Value::Vec3f).size, 66_624);
        assert_eq!(leaf(Value::Float).size, 2_144);
        assert_eq!(leaf(Value::Vec3f).size, 6_272);
        assert_eq!(leaf(Value::Vec3f).values, 128);
        assert_eq!(fn_leaf_size(4), 352);
        assert_eq!(fn_leaf_size(8), 608);
        assert_eq!(fn_leaf_size(16), 1_120);
    }
}
