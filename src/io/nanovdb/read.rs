//! A reader of the NanoVDB files nimbus writes (breadth-first grids of float, Vec3f, Fp4, Fp8,
//! Fp16 and FpN; codec NONE): the grids' records, their leaves decoded, and the checksum
//! recomputed. For `nimbus inspect` and the tests; renderers read the files with NanoVDB itself.
use super::layout::{self as l, Value};
use super::write::code_at;
use super::{GridType, MAGIC, VERSION};
use crate::error::{Error, Result};
use crate::ground::{Leaf, LEAF_VOXELS};
use std::path::Path;

/// One grid of a file, decoded.
#[derive(Debug, Clone)]
pub struct NanoFileGrid {
    pub name: String,
    pub grid_type: GridType,
    /// NanoVDB `GridClass` value.
    pub class: u32,
    pub voxel_size: f64,
    /// World position of voxel (0, 0, 0)'s centre.
    pub origin: [f64; 3],
    pub active_voxels: u64,
    /// Index bbox of the active voxels (inclusive); `None` when empty.
    pub bbox: Option<([i32; 3], [i32; 3])>,
    pub bytes: u64,
    /// The stored checksum equals the recomputed one (full, or partial when stored so).
    pub checksum_ok: bool,
    pub leaves: Leaves,
}

/// The leaves in file order, values decoded to float (quantised codes x quantum + minimum).
#[derive(Debug, Clone)]
pub enum Leaves {
    Float(Vec<Leaf<f32>>),
    Vec3(Vec<Leaf<[f32; 3]>>),
}

fn bad(what: &str) -> Error {
    Error::InvalidInput(format!("not a NanoVDB file nimbus can read: {what}"))
}

fn u16_at(b: &[u8], at: usize) -> Result<u16> {
    b.get(at..at + 2)
        .map(|s| u16::from_le_bytes([s[0], s[1]]))
        .ok_or_else(|| bad("truncated"))
}
fn u32_at(b: &[u8], at: usize) -> Result<u32> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes(s.try_into().unwrap_or_default()))
        .ok_or_else(|| bad("truncated"))
}
fn u64_at(b: &[u8], at: usize) -> Result<u64> {
    b.get(at..at + 8)
        .map(|s| u64::from_le_bytes(s.try_into().unwrap_or_default()))
        .ok_or_else(|| bad("truncated"))
}
fn i32_at(b: &[u8], at: usize) -> Result<i32> {
    u32_at(b, at).map(|v| v as i32)
}
fn f32_at(b: &[u8], at: usize) -> Result<f32> {
    u32_at(b, at).map(f32::from_bits)
}
fn f64_at(b: &[u8], at: usize) -> Result<f64> {
    u64_at(b, at).map(f64::from_bits)
}

pub fn read_file(path: &Path) -> Result<Vec<NanoFileGrid>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_bytes(&bytes).map_err(|e| match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!("{}: {m}", path.display())),
        other => other,
    })
}

pub fn read_bytes(b: &[u8]) -> Result<Vec<NanoFileGrid>> {
    let mut at = 0;
    let mut out = Vec::new();
    while at < b.len() {
        if u64_at(b, at)? != MAGIC {
            return Err(bad("wrong magic number"));
        }
        if u32_at(b, at + 8)? >> 21 != VERSION >> 21 {
            return Err(bad("not NanoVDB major version 32"));
        }
        let count = u16_at(b, at + 12)? as usize;
        if u16_at(b, at + 14)? != 0 {
            return Err(bad("compressed (nimbus writes codec NONE)"));
        }
        at += l::FILE_HEADER;
        let mut sizes = Vec::new();
        for _ in 0..count {
            let size = u64_at(b, at + l::meta::FILE_SIZE)? as usize;
            let name_size = u32_at(b, at + l::meta::NAME_SIZE)? as usize;
            sizes.push(size);
            at += l::meta::SIZE + name_size;
        }
        for size in sizes {
            let buf = b.get(at..at + size).ok_or_else(|| bad("truncated grid"))?;
            out.push(read_grid(buf)?);
            at += size;
        }
    }
    Ok(out)
}

fn read_grid(b: &[u8]) -> Result<NanoFileGrid> {
    use l::grid as g;
    if u64_at(b, g::MAGIC)? != MAGIC {
        return Err(bad("grid magic"));
    }
    let name_bytes = &b[g::NAME..g::NAME + g::NAME_SIZE];
    let end = name_bytes
        .iter()
        .position(|&c| c == 0)
        .unwrap_or(g::NAME_SIZE);
    let name = String::from_utf8_lossy(&name_bytes[..end]).into_owned();
    let grid_type = GridType::from_u32(u32_at(b, g::TYPE)?).ok_or_else(|| bad("grid type"))?;
    let value = if grid_type == GridType::Vec3f {
        Value::Vec3f
    } else {
        Value::Float
    };
    let tree = g::SIZE;
    let node_off = |k: usize| u64_at(b, tree + l::tree::NODE_OFFSET + 8 * k).map(|o| o as usize);
    let node_count = |k: usize| u32_at(b, tree + l::tree::NODE_COUNT + 4 * k).map(|c| c as usize);
    let (leaf_count, lower_count, upper_count) = (node_count(0)?, node_count(1)?, node_count(2)?);
    let root = tree + node_off(3)?;
    let table = u32_at(b, root + l::ROOT_TABLE_SIZE)? as usize;
    let root_end = root + l::root(value).size + table * l::TILE_SIZE;
    let bbox = {
        let lo = [0, 1, 2].map(|a| i32_at(b, root + l::ROOT_BBOX + 4 * a).unwrap_or(i32::MAX));
        let hi = [0, 1, 2].map(|a| i32_at(b, root + l::ROOT_BBOX + 12 + 4 * a).unwrap_or(i32::MIN));
        (0..3).all(|a| lo[a] <= hi[a]).then_some((lo, hi))
    };

    // Leaves, sequential from the first (breadth-first layout).
    let mut at = tree + node_off(0)?;
    let mut nodes: Vec<(usize, usize)> = Vec::new();
    let up = l::upper(value).size;
    let low = l::lower(value).size;
    if upper_count > 0 {
        let first = tree + node_off(2)?;
        nodes.extend((0..upper_count).map(|i| (first + i * up, up)));
    }
    if lower_count > 0 {
        let first = tree + node_off(1)?;
        nodes.extend((0..lower_count).map(|i| (first + i * low, low)));
    }
    let mut float_leaves = Vec::new();
    let mut vec_leaves = Vec::new();
    for _ in 0..leaf_count {
        let head = b
            .get(at..at + l::FN_CODES)
            .ok_or_else(|| bad("truncated leaf"))?;
        let origin = [0, 1, 2].map(|a| i32_at(head, l::LEAF_BBOX_MIN + 4 * a).unwrap_or(0) & !7);
        let mut mask = [0u64; 8];
        for (w, m) in mask.iter_mut().enumerate() {
            *m = u64_at(head, l::LEAF_MASK + 8 * w)?;
        }
        let bits = match grid_type {
            GridType::Fp4 => 4,
            GridType::Fp8 => 8,
            GridType::Fp16 => 16,
            GridType::FpN => 1 << (head[l::LEAF_FLAGS] >> 5),
            _ => 0,
        };
        let (size, crc_len) = match grid_type {
            GridType::Float | GridType::Vec3f => (l::leaf(value).size, l::leaf(value).size),
            GridType::FpN => (l::fn_leaf_size(bits as usize), l::FN_CODES),
            _ => (
                l::fn_leaf_size(bits as usize),
                l::fn_leaf_size(bits as usize),
            ),
        };
        let leaf = b.get(at..at + size).ok_or_else(|| bad("truncated leaf"))?;
        nodes.push((at, crc_len));
        match grid_type {
            GridType::Vec3f => {
                let base = l::leaf(value).values;
                let mut values = Box::new([[0f32; 3]; LEAF_VOXELS]);
                for (n, v) in values.iter_mut().enumerate() {
                    for (c, x) in v.iter_mut().enumerate() {
                        *x = f32_at(leaf, base + 12 * n + 4 * c)?;
                    }
                }
                vec_leaves.push(Leaf {
                    origin,
                    values,
                    mask,
                });
            }
            _ => {
                // float values, or codes x quantum + minimum
                let base = l::leaf(value).values;
                let (min, q) = (f32_at(leaf, l::FN_MINIMUM)?, f32_at(leaf, l::FN_QUANTUM)?);
                let mut values = Box::new([0f32; LEAF_VOXELS]);
                for (n, v) in values.iter_mut().enumerate() {
                    *v = match grid_type {
                        GridType::Float => f32_at(leaf, base + 4 * n)?,
                        _ => code_at(leaf, n, bits) as f32 * q + min,
                    };
                }
                float_leaves.push(Leaf {
                    origin,
                    values,
                    mask,
                });
            }
        }
        at += size;
    }

    let stored = u64_at(b, g::CHECKSUM)?;
    let crc0 = crc32fast::hash(b.get(16..root_end).ok_or_else(|| bad("truncated root"))?);
    let partial = (stored >> 32) as u32 == 0xffff_ffff;
    let crc1 = if partial || nodes.is_empty() {
        0xffff_ffff
    } else {
        let crcs: Vec<u8> = nodes
            .iter()
            .flat_map(|&(at, len)| (crc32fast::hash(&b[at..at + len]) as u64).to_le_bytes())
            .collect();
        crc32fast::hash(&crcs)
    };
    let m = g::MAP;
    Ok(NanoFileGrid {
        name,
        grid_type,
        class: u32_at(b, g::CLASS)?,
        voxel_size: f64_at(b, g::VOXEL_SIZE)?,
        origin: [
            f64_at(b, m + 232)?,
            f64_at(b, m + 240)?,
            f64_at(b, m + 248)?,
        ],
        active_voxels: u64_at(b, tree + l::tree::VOXEL_COUNT)?,
        bbox,
        bytes: b.len() as u64,
        checksum_ok: stored == (crc0 as u64 | ((crc1 as u64) << 32)),
        leaves: if grid_type == GridType::Vec3f {
            Leaves::Vec3(vec_leaves)
        } else {
            Leaves::Float(float_leaves)
        },
    })
}
