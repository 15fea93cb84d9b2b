//! Per-frame Z-slice atlas (flipbook) of the density grid as OpenEXR: the XY slices of the
//! active bounding box laid out left to right, top to bottom (slice k at column k % columns,
//! row k / columns), +y up inside each tile; one channel `density`, f32 or f16, ZIP (16
//! scanlines), increasing line order. Header attributes describe the layout and the grid so a
//! compositor can map a pixel back to a voxel:
//! `slices`, `atlasColumns`, `atlasRows` (int), `gridSize` (v3i, voxels of the bbox),
//! `bboxMin` (v3i, index of the first voxel), `voxelSize` (double, metres), `origin` (v3f,
//! world position of the centre of voxel (0,0,0)). Attributes are written sorted by name (as
//! OpenEXR does) so the same grid always gives the same bytes.
use crate::error::{Error, Result};
use crate::ground::SparseGrid;
use crate::io::atomic::write_atomic;
use exr::prelude::*;
use std::path::Path;

/// Atlas geometry for a bbox of `size` voxels: (columns, rows), near-square.
pub fn atlas_layout(size: [usize; 3]) -> (usize, usize) {
    let nz = size[2];
    if nz == 0 {
        return (0, 0);
    }
    let cols = ((nz as f64).sqrt().ceil() as usize).max(1);
    (cols, nz.div_ceil(cols))
}

fn exr_error(e: exr::error::Error) -> Error {
    Error::Runtime(format!("EXR encoding failed: {e}"))
}

/// Encodes the density atlas of `grid` to EXR bytes.
pub fn encode_density_atlas(grid: &SparseGrid<f32>, half: bool) -> Result<Vec<u8>> {
    let bbox = grid.active_bbox();
    let (lo, size) = match bbox {
        Some((lo, hi)) => (lo, [0, 1, 2].map(|a| (hi[a] - lo[a] + 1) as usize)),
        None => ([0; 3], [0; 3]),
    };
    let (cols, rows) = atlas_layout(size);
    let (w, h) = if cols == 0 {
        (1, 1)
    } else {
        (cols * size[0], rows * size[1])
    };
    if w.saturating_mul(h) > (1usize << 31) || w > i32::MAX as usize / 2 {
        return Err(Error::InvalidInput(format!(
            "density bbox {size:?} is too large for an EXR atlas ({w}x{h} pixels)"
        )));
    }
    let mut pix = vec![0f32; w * h];
    if cols > 0 {
        for leaf in &grid.leaves {
            for (word, &m0) in leaf.mask.iter().enumerate() {
                let mut m = m0;
                while m != 0 {
                    let n = word * 64 + m.trailing_zeros() as usize;
                    m &= m - 1;
                    let x = (leaf.origin[0] + (n >> 6) as i32 - lo[0]) as usize;
                    let y = (leaf.origin[1] + ((n >> 3) & 7) as i32 - lo[1]) as usize;
                    let k = (leaf.origin[2] + (n & 7) as i32 - lo[2]) as usize;
                    let px = (k % cols) * size[0] + x;
                    let py = (k / cols) * size[1] + (size[1] - 1 - y);
                    pix[py * w + px] = leaf.values[n];
                }
            }
        }
    }
    let samples = if half {
        FlatSamples::F16(pix.iter().map(|&v| f16::from_f32(v)).collect())
    } else {
        FlatSamples::F32(pix)
    };
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
        "density", samples,
    )]));
    let mut attrs = LayerAttributes::default();
    let t = &grid.transform;
    let other = &mut attrs.other;
    other.insert(Text::from("slices"), AttributeValue::I32(size[2] as i32));
    other.insert(Text::from("atlasColumns"), AttributeValue::I32(cols as i32));
    other.insert(Text::from("atlasRows"), AttributeValue::I32(rows as i32));
    let s = size.map(|v| v as i32);
    other.insert(
        Text::from("gridSize"),
        AttributeValue::IntVec3((s[0], s[1], s[2])),
    );
    other.insert(
        Text::from("bboxMin"),
        AttributeValue::IntVec3((lo[0], lo[1], lo[2])),
    );
    other.insert(Text::from("voxelSize"), AttributeValue::F64(t.voxel_size));
    other.insert(
        Text::from("origin"),
        AttributeValue::FloatVec3((t.origin[0] as f32, t.origin[1] as f32, t.origin[2] as f32)),
    );
    let encoding = Encoding {
        compression: exr::compression::Compression::ZIP16,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new((w, h), attrs, encoding, channels);
    let image = Image::from_layer(layer);
    let mut buf = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut buf).map_err(exr_error)?;
    let mut bytes = buf.into_inner();
    sort_header_attributes(&mut bytes)?;
    Ok(bytes)
}

/// Reorders the attributes of a single-part EXR header by name, in place. The exr crate writes
/// custom attributes in hash-map order (different each run); sorting keeps the header length,
/// so the offset table after it stays valid.
fn sort_header_attributes(bytes: &mut [u8]) -> Result<()> {
    let broken = || Error::Runtime("EXR header could not be parsed for sorting".into());
    let mut p = 8; // magic + version
    let cstr = |b: &[u8], p: usize| -> Option<usize> {
        b.get(p..)?.iter().position(|&c| c == 0).map(|i| p + i)
    };
    let mut attrs: Vec<(Vec<u8>, std::ops::Range<usize>)> = Vec::new();
    let start = p;
    loop {
        let name_end = cstr(bytes, p).ok_or_else(broken)?;
        if name_end == p {
            break; // end of header
        }
        let type_end = cstr(bytes, name_end + 1).ok_or_else(broken)?;
        let size_at = type_end + 1;
        let size = bytes
            .get(size_at..size_at + 4)
            .map(|s| i32::from_le_bytes(s.try_into().unwrap()))
            .filter(|&s| s >= 0)
            .ok_or_else(broken)? as usize;
        let end = size_at + 4 + size;
        if end > bytes.len() {
            return Err(broken());
        }
        attrs.push((bytes[p..name_end].to_vec(), p..end));
        p = end;
    }
    let mut sorted = attrs.clone();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    let mut out = Vec::with_capacity(p - start);
    for (_, r) in &sorted {
        out.extend_from_slice(&bytes[r.clone()]);
    }
    bytes[start..p].copy_from_slice(&out);
    Ok(())
}

/// Writes the density atlas atomically; returns the file size.
pub fn write_density_atlas(path: &Path, grid: &SparseGrid<f32>, half: bool) -> Result<u64> {
    let bytes = encode_density_atlas(grid, half)?;
    write_atomic(path, &bytes)?;
    Ok(bytes.len() as u64)
}
