//! Reader for OpenVDB files of formats 222-225 (OpenVDB 3 to 13: the same layout for the grids
//! read here): `Tree_float_5_4_3` and `Tree_vec3s_5_4_3` (optionally `_HalfFloat`) with
//! uniform-scale transforms, tiles (active or not) in the root and internal nodes, any of none /
//! zip / blosc with or without the active mask, grid instances. Grids of other types (double,
//! int, bool, points, ...) are skipped and listed in [`ReadFile::skipped`]. Layout as OpenVDB's
//! `RootNode::readTopology`, `InternalNode::readTopology`, `LeafNode::readBuffers` and
//! `io::readCompressedValues`. Anything else, or a damaged file, is an `Error::InvalidInput`
//! naming the problem, never a panic.
use super::write::VdbValue;
use super::{
    blosc, GridData, MetaValue, COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC, COMPRESS_ZIP, MAGIC,
};
use crate::error::{Error, Result};
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use std::io::Read;
use std::path::Path;

/// File format versions read: 222 (per-grid compression, node-mask compression) to 225
/// (OpenVDB 13, which only adds half grids, a type skipped here).
pub const READ_VERSIONS: std::ops::RangeInclusive<u32> = 222..=225;

/// A tile of the root (edge 4096 voxels) or of an internal node (edge 128 or 8): one value for
/// the whole cube of voxels from `origin`. For vector grids `value` is the vector's length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tile {
    pub origin: [i32; 3],
    pub edge: u32,
    pub value: f32,
    pub active: bool,
}

impl Tile {
    pub fn voxels(&self) -> u64 {
        (self.edge as u64).pow(3)
    }
}

/// A grid as read back.
#[derive(Debug, Clone)]
pub struct ReadGrid {
    /// The grid's name (OpenVDB's unique-name suffix `\x1e N` stripped).
    pub name: String,
    /// Type name as in the file (with `_HalfFloat` when stored as half).
    pub type_name: String,
    pub half: bool,
    /// Name of the grid whose tree this one shares (OpenVDB instancing), if any.
    pub instance_parent: Option<String>,
    /// Stream compression flags (`COMPRESS_*`).
    pub compression: u32,
    pub metadata: Vec<(String, MetaValue)>,
    /// The leaves' active voxels (inactive ones hold the background: the `SparseGrid` contract).
    pub data: GridData,
    /// Tiles that are active or hold a value other than the background (a level set's inside),
    /// in file order.
    pub tiles: Vec<Tile>,
    /// Float grids: the leaves (with every value) whose inactive voxels hold values other than
    /// the background, as a level set's narrow band does inside (the sign of the distance).
    pub inactive_leaves: Vec<Leaf<f32>>,
}

impl ReadGrid {
    pub fn meta(&self, key: &str) -> Option<&MetaValue> {
        self.metadata.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }
    pub fn transform(&self) -> GridTransform {
        match &self.data {
            GridData::Float(g) => g.transform,
            GridData::Vec3(g) => g.transform,
        }
    }
    /// The `class` metadata ("fog volume", "level set", ...), "unknown" when absent.
    pub fn class(&self) -> String {
        self.meta("class")
            .map(|v| v.to_string())
            .unwrap_or_else(|| "unknown".into())
    }
    /// Active voxels in leaves and in active tiles.
    pub fn active_voxel_count(&self) -> u64 {
        let leaves = match &self.data {
            GridData::Float(g) => g.active_voxel_count(),
            GridData::Vec3(g) => g.active_voxel_count(),
        };
        leaves
            + self
                .tiles
                .iter()
                .filter(|t| t.active)
                .map(Tile::voxels)
                .sum::<u64>()
    }
}

#[derive(Debug, Clone)]
pub struct ReadFile {
    pub version: u32,
    pub library: (u32, u32),
    pub uuid: String,
    pub metadata: Vec<(String, MetaValue)>,
    pub grids: Vec<ReadGrid>,
    /// Grids of types this reader does not read: (name, type name as in the file).
    pub skipped: Vec<(String, String)>,
}

impl ReadFile {
    pub fn grid(&self, name: &str) -> Option<&ReadGrid> {
        self.grids.iter().find(|g| g.name == name)
    }
}

fn bad(msg: impl std::fmt::Display) -> Error {
    Error::InvalidInput(format!("not a VDB file nimbus can read: {msg}"))
}

struct Cur<'a> {
    b: &'a [u8],
    p: usize,
}

impl<'a> Cur<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self
            .p
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| bad(format!("truncated at byte {}", self.p)))?;
        let s = &self.b[self.p..end];
        self.p = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self) -> Result<[u8; N]> {
        Ok(self.take(N)?.try_into().unwrap())
    }
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.arr()?))
    }
    fn i32(&mut self) -> Result<i32> {
        Ok(i32::from_le_bytes(self.arr()?))
    }
    fn i64(&mut self) -> Result<i64> {
        Ok(i64::from_le_bytes(self.arr()?))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.arr()?))
    }
    fn string(&mut self) -> Result<String> {
        let n = self.u32()? as usize;
        let s = self.take(n)?;
        String::from_utf8(s.to_vec()).map_err(|_| bad("a string is not UTF-8"))
    }
    fn mask(&mut self, words: usize) -> Result<Vec<u64>> {
        let s = self.take(words * 8)?;
        Ok(s.chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    fn remaining(&self) -> usize {
        self.b.len() - self.p
    }
    /// A count of items each at least `min_bytes` long, checked against what is left.
    fn count(&mut self, min_bytes: usize, what: &str) -> Result<usize> {
        let n = self.u32()? as usize;
        if n.saturating_mul(min_bytes) > self.remaining() {
            return Err(bad(format!("{what} count {n} exceeds the file")));
        }
        Ok(n)
    }
}

fn read_metadata(c: &mut Cur) -> Result<Vec<(String, MetaValue)>> {
    let n = c.count(12, "metadata")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let name = c.string()?;
        let ty = c.string()?;
        let size = c.u32()? as usize;
        let b = c.take(size)?;
        let f32_at = |i: usize| f32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap());
        let i32_at = |i: usize| i32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap());
        let f64_at = |i: usize| f64::from_le_bytes(b[8 * i..8 * i + 8].try_into().unwrap());
        let want = |n: usize| {
            if size == n {
                Ok(())
            } else {
                Err(bad(format!(
                    "metadata '{name}' of type {ty} has {size} bytes"
                )))
            }
        };
        let v = match ty.as_str() {
            "string" => MetaValue::String(String::from_utf8_lossy(b).into_owned()),
            "int32" => want(4).map(|_| MetaValue::Int32(i32_at(0)))?,
            "int64" => {
                want(8).map(|_| MetaValue::Int64(i64::from_le_bytes(b.try_into().unwrap())))?
            }
            "float" => want(4).map(|_| MetaValue::Float(f32_at(0)))?,
            "double" => want(8).map(|_| MetaValue::Double(f64_at(0)))?,
            "bool" => want(1).map(|_| MetaValue::Bool(b[0] != 0))?,
            "vec3i" => want(12).map(|_| MetaValue::Vec3i([i32_at(0), i32_at(1), i32_at(2)]))?,
            "vec3s" => want(12).map(|_| {
                MetaValue::Vec3d([f32_at(0) as f64, f32_at(1) as f64, f32_at(2) as f64])
            })?,
            "vec3d" => want(24).map(|_| MetaValue::Vec3d([f64_at(0), f64_at(1), f64_at(2)]))?,
            _ => continue, // other types are skipped (their size is known)
        };
        out.push((name, v));
    }
    Ok(out)
}

fn read_transform(c: &mut Cur) -> Result<GridTransform> {
    let ty = c.string()?;
    let v3 = |c: &mut Cur| -> Result<[f64; 3]> { Ok([c.f64()?, c.f64()?, c.f64()?]) };
    let translate = match ty.as_str() {
        "UniformScaleMap" | "ScaleMap" => [0.0; 3],
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => v3(c)?,
        other => return Err(bad(format!("transform map '{other}' is not supported"))),
    };
    let scale = v3(c)?;
    for _ in 0..4 {
        v3(c)?;
    }
    let s = scale[0];
    if !(s.is_finite() && s > 0.0) || scale.iter().any(|&x| x != s) {
        return Err(bad(format!(
            "voxel size {scale:?} is not uniform and positive"
        )));
    }
    if translate.iter().any(|x| !x.is_finite()) {
        return Err(bad("transform translation is not finite"));
    }
    Ok(GridTransform {
        voxel_size: s,
        origin: translate,
    })
}

fn read_value<T: VdbValue>(b: &[u8], half: bool) -> T {
    let mut c = [0f32; 3];
    for (i, x) in c.iter_mut().take(T::COMPS).enumerate() {
        *x = if half {
            half::f16::from_le_bytes([b[2 * i], b[2 * i + 1]]).to_f32()
        } else {
            f32::from_le_bytes(b[4 * i..4 * i + 4].try_into().unwrap())
        };
    }
    T::from_comps(c)
}

fn full_value<T: VdbValue>(c: &mut Cur) -> Result<T> {
    let b = c.take(4 * T::COMPS)?;
    Ok(read_value(b, false))
}

fn bit(mask: &[u64], n: usize) -> bool {
    mask[n / 64] >> (n % 64) & 1 == 1
}

/// `io::readData`: `nbytes` of values with the stream's codec.
fn read_data(c: &mut Cur, nbytes: usize, flags: u32) -> Result<Vec<u8>> {
    if flags & (COMPRESS_BLOSC | COMPRESS_ZIP) == 0 {
        return Ok(c.take(nbytes)?.to_vec());
    }
    let n = c.i64()?;
    if n <= 0 {
        if n.unsigned_abs() as usize != nbytes {
            return Err(bad(format!(
                "stored block of {} bytes, expected {nbytes}",
                -n
            )));
        }
        return Ok(c.take(nbytes)?.to_vec());
    }
    let data = c.take(usize::try_from(n).map_err(|_| bad("block size"))?)?;
    if flags & COMPRESS_BLOSC != 0 {
        blosc::decompress(data, nbytes)
    } else {
        let mut out = Vec::with_capacity(nbytes);
        flate2::read::ZlibDecoder::new(data)
            .take(nbytes as u64 + 1)
            .read_to_end(&mut out)
            .map_err(|e| bad(format!("zip block: {e}")))?;
        if out.len() != nbytes {
            return Err(bad("zip block has the wrong size"));
        }
        Ok(out)
    }
}

/// `io::readCompressedValues` for `count` values under `value_mask`, expanded to all `count`.
fn read_values<T: VdbValue>(
    c: &mut Cur,
    count: usize,
    value_mask: &[u64],
    flags: u32,
    half: bool,
    background: T,
) -> Result<Vec<T>> {
    let metadata = c.u8()?;
    if metadata > 6 {
        return Err(bad(format!("value block metadata {metadata}")));
    }
    let masked = flags & COMPRESS_ACTIVE_MASK != 0 && metadata != 6;
    let neg = T::from_comps(background.comps().map(|x| -x));
    let mut inactive = [if metadata == 0 { background } else { neg }, background];
    if matches!(metadata, 2 | 4 | 5) {
        inactive[0] = full_value(c)?;
        if metadata == 5 {
            inactive[1] = full_value(c)?;
        }
    }
    let selection = if matches!(metadata, 3..=5) {
        Some(c.mask(count / 64)?)
    } else {
        None
    };
    let stored = if masked {
        value_mask.iter().map(|w| w.count_ones() as usize).sum()
    } else {
        count
    };
    let elem = if half { 2 } else { 4 } * T::COMPS;
    let raw = read_data(c, stored * elem, flags)?;
    let vals = raw.chunks_exact(elem).map(|b| read_value::<T>(b, half));
    if !masked {
        return Ok(vals.collect());
    }
    let mut out = vec![background; count];
    let mut vals = vals;
    for (n, o) in out.iter_mut().enumerate() {
        *o = if bit(value_mask, n) {
            vals.next().ok_or_else(|| bad("too few values"))?
        } else {
            let sel = selection.as_ref().is_some_and(|s| bit(s, n));
            inactive[sel as usize]
        };
    }
    Ok(out)
}

/// What a tree holds: its active leaf voxels, its tiles that matter, and the leaves whose
/// inactive voxels hold values other than the background.
struct Tree<T> {
    grid: SparseGrid<T>,
    tiles: Vec<Tile>,
    inactive_leaves: Vec<Leaf<T>>,
}

/// A value as one number: itself, or a vector's length.
fn scalar<T: VdbValue>(v: &T) -> f32 {
    if T::COMPS == 1 {
        v.comps()[0]
    } else {
        v.comps().iter().map(|c| c * c).sum::<f32>().sqrt()
    }
}

/// The tiles of an internal node's value table worth keeping: active, or not the background.
/// `edge` is the child's edge in voxels and `log2` the node's own log2 dimension.
fn node_tiles<T: VdbValue>(
    origin: [i32; 3],
    log2: u32,
    edge: u32,
    values: &[T],
    child: &[u64],
    value: &[u64],
    background: T,
) -> Vec<Tile> {
    let mut out = Vec::new();
    let dim = 1usize << log2;
    for (n, v) in values.iter().enumerate() {
        if bit(child, n) {
            continue;
        }
        let active = bit(value, n);
        if !active && *v == background {
            continue;
        }
        let (x, y, z) = (n >> (2 * log2), (n >> log2) & (dim - 1), n & (dim - 1));
        let o = [
            origin[0] + (x as u32 * edge) as i32,
            origin[1] + (y as u32 * edge) as i32,
            origin[2] + (z as u32 * edge) as i32,
        ];
        let tile = Tile {
            origin: o,
            edge,
            value: scalar(v),
            active,
        };
        out.push(tile);
    }
    out
}

fn read_tree<T: VdbValue>(c: &mut Cur, flags: u32, half: bool, name: &str) -> Result<Tree<T>> {
    if c.u32()? != 1 {
        return Err(bad("buffer count other than 1"));
    }
    let background: T = full_value(c)?;
    let root_tiles = c.count(4 * (3 + T::COMPS) + 1, "root tile")?;
    let children = c.count(12 + 1024 * 8, "root child")?;
    let mut tiles: Vec<Tile> = Vec::new();
    for _ in 0..root_tiles {
        let origin = [c.i32()?, c.i32()?, c.i32()?];
        let v: T = full_value(c)?;
        let active = c.u8()? != 0;
        if origin.iter().any(|o| o & 4095 != 0) {
            return Err(bad("root tile origin not aligned to 4096"));
        }
        if active || v != background {
            let tile = Tile {
                origin,
                edge: 4096,
                value: scalar(&v),
                active,
            };
            tiles.push(tile);
        }
    }
    let mut origins: Vec<[i32; 3]> = Vec::new();
    let mut masks: Vec<[u64; 8]> = Vec::new();
    for _ in 0..children {
        let o5 = [c.i32()?, c.i32()?, c.i32()?];
        if o5.iter().any(|v| v & 4095 != 0) {
            return Err(bad("root child origin not aligned to 4096"));
        }
        let child5 = c.mask(512)?;
        let value5 = c.mask(512)?;
        let v5 = read_values::<T>(c, 32768, &value5, flags, half, background)?;
        tiles.extend(node_tiles(o5, 5, 128, &v5, &child5, &value5, background));
        for n5 in (0..32768).filter(|&n| bit(&child5, n)) {
            let o4 = [
                o5[0] + (((n5 >> 10) & 31) << 7) as i32,
                o5[1] + (((n5 >> 5) & 31) << 7) as i32,
                o5[2] + ((n5 & 31) << 7) as i32,
            ];
            let child4 = c.mask(64)?;
            let value4 = c.mask(64)?;
            let v4 = read_values::<T>(c, 4096, &value4, flags, half, background)?;
            tiles.extend(node_tiles(o4, 4, 8, &v4, &child4, &value4, background));
            for n4 in (0..4096).filter(|&n| bit(&child4, n)) {
                origins.push([
                    o4[0] + (((n4 >> 8) & 15) << 3) as i32,
                    o4[1] + (((n4 >> 4) & 15) << 3) as i32,
                    o4[2] + ((n4 & 15) << 3) as i32,
                ]);
                masks.push(c.mask(8)?.try_into().unwrap());
            }
        }
    }
    let mut leaves = Vec::with_capacity(origins.len());
    let mut inactive_leaves = Vec::new();
    for (origin, mask) in origins.into_iter().zip(masks) {
        let again: [u64; 8] = c.mask(8)?.try_into().unwrap();
        if again != mask {
            return Err(bad("leaf mask in the buffers differs from the topology"));
        }
        let v = read_values::<T>(c, LEAF_VOXELS, &mask, flags, half, background)?;
        let mut values = Box::new([background; LEAF_VOXELS]);
        let mut other_inactive = false;
        for (n, (dst, src)) in values.iter_mut().zip(&v).enumerate() {
            // Inactive voxels hold the background (the SparseGrid contract); those that do not
            // (a level set's inside) keep the whole leaf in `inactive_leaves`.
            if bit(&mask, n) {
                *dst = *src;
            } else if *src != background {
                other_inactive = true;
            }
        }
        if other_inactive {
            let mut all = Box::new([background; LEAF_VOXELS]);
            all.copy_from_slice(&v);
            inactive_leaves.push(Leaf {
                origin,
                values: all,
                mask,
            });
        }
        leaves.push(Leaf {
            origin,
            values,
            mask,
        });
    }
    leaves.sort_by_key(|l| l.origin);
    Ok(Tree {
        grid: SparseGrid {
            name: name.to_string(),
            background,
            transform: GridTransform {
                voxel_size: 1.0,
                origin: [0.0; 3],
            },
            leaves,
        },
        tiles,
        inactive_leaves,
    })
}

/// Parses a whole VDB file held in memory.
pub fn read_bytes(bytes: &[u8]) -> Result<ReadFile> {
    let mut c = Cur { b: bytes, p: 0 };
    if c.i64().ok() != Some(MAGIC) {
        return Err(bad("bad magic number"));
    }
    let version = c.u32()?;
    if !READ_VERSIONS.contains(&version) {
        return Err(bad(format!(
            "file format {version} (nimbus reads {} to {})",
            READ_VERSIONS.start(),
            READ_VERSIONS.end()
        )));
    }
    let library = (c.u32()?, c.u32()?);
    if c.u8()? != 1 {
        return Err(bad("file without grid offsets"));
    }
    let uuid = String::from_utf8_lossy(c.take(36)?).into_owned();
    let metadata = read_metadata(&mut c)?;
    let count = c.count(12 + 24, "grid")?;
    let mut grids: Vec<ReadGrid> = Vec::with_capacity(count);
    // unique names (OpenVDB's `name\x1eN` for repeated names), as instances refer to them
    let mut unique: Vec<String> = Vec::with_capacity(count);
    let mut skipped: Vec<(String, String)> = Vec::new();
    let mut skipped_unique: Vec<String> = Vec::new();
    for _ in 0..count {
        let unique_name = c.string()?;
        let name = unique_name
            .split('\x1e')
            .next()
            .unwrap_or_default()
            .to_string();
        let type_name = c.string()?;
        let parent = c.string()?;
        let (grid_pos, _block_pos, end_pos) = (c.i64()?, c.i64()?, c.i64()?);
        let in_file = |p: i64| usize::try_from(p).ok().filter(|&p| p <= bytes.len());
        let (Some(gp), Some(ep)) = (in_file(grid_pos), in_file(end_pos)) else {
            return Err(bad(format!("grid '{name}': offsets outside the file")));
        };
        if gp != c.p || ep < gp {
            return Err(bad(format!("grid '{name}': inconsistent offsets")));
        }
        let (base, half) = match type_name.strip_suffix("_HalfFloat") {
            Some(b) => (b, true),
            None => (type_name.as_str(), false),
        };
        let readable = matches!(base, "Tree_float_5_4_3" | "Tree_vec3s_5_4_3");
        if !readable || skipped_unique.contains(&parent) {
            // the offsets say where the next grid starts
            c.p = ep;
            skipped.push((name, type_name.clone()));
            skipped_unique.push(unique_name);
            continue;
        }
        let compression = c.u32()?;
        let gmeta = read_metadata(&mut c)?;
        let transform = read_transform(&mut c)?;
        let (mut data, tiles, inactive_leaves) = if !parent.is_empty() {
            let p = unique
                .iter()
                .position(|u| *u == parent)
                .map(|i| &grids[i])
                .ok_or_else(|| bad(format!("grid '{name}': instance of unknown '{parent}'")))?;
            if p.type_name != type_name {
                return Err(bad(format!("grid '{name}': type differs from its parent")));
            }
            let mut d = p.data.clone();
            match &mut d {
                GridData::Float(g) => g.name = name.clone(),
                GridData::Vec3(g) => g.name = name.clone(),
            }
            (d, p.tiles.clone(), p.inactive_leaves.clone())
        } else if base == "Tree_float_5_4_3" {
            let t = read_tree::<f32>(&mut c, compression, half, &name)?;
            (GridData::Float(t.grid), t.tiles, t.inactive_leaves)
        } else {
            let t = read_tree::<[f32; 3]>(&mut c, compression, half, &name)?;
            (GridData::Vec3(t.grid), t.tiles, Vec::new())
        };
        match &mut data {
            GridData::Float(g) => g.transform = transform,
            GridData::Vec3(g) => g.transform = transform,
        }
        if c.p != ep {
            return Err(bad(format!(
                "grid '{name}': end offset does not match the data"
            )));
        }
        unique.push(unique_name);
        grids.push(ReadGrid {
            name,
            type_name: type_name.clone(),
            half,
            instance_parent: (!parent.is_empty())
                .then(|| parent.split('\x1e').next().unwrap_or_default().to_string()),
            compression,
            metadata: gmeta,
            data,
            tiles,
            inactive_leaves,
        });
    }
    Ok(ReadFile {
        version,
        library,
        uuid,
        metadata,
        grids,
        skipped,
    })
}

/// Reads a VDB file (written by nimbus, OpenVDB, Houdini, ...).
pub fn read_file(path: &Path) -> Result<ReadFile> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_bytes(&bytes).map_err(|e| Error::InvalidInput(format!("{}: {e}", path.display())))
}
