//! Blosc1 frames with LZ4 and byte shuffle, written and read in Rust (lz4_flex), laid out as
//! c-blosc 1.21 (the library OpenVDB 10 links) lays them out, so that OpenVDB, pyopenvdb and
//! vdb-rs decompress them with their own libblosc.
//!
//! Frame: 16-byte header (format version 2, LZ4 format version 1, flags, type size, uncompressed
//! bytes, block size, frame bytes), then either the raw bytes (flag MEMCPYED) or one start
//! offset per block followed by each block: `nsplits` streams of `i32 size + LZ4 block` (a
//! stream whose size equals its uncompressed size is stored raw).
use crate::error::{Error, Result};

const VERSION_FORMAT: u8 = 2;
const VERSION_LZ4: u8 = 1;
const FLAG_SHUFFLE: u8 = 0x01;
const FLAG_MEMCPYED: u8 = 0x02;
const FLAG_BITSHUFFLE: u8 = 0x04;
const FLAG_NOSPLIT: u8 = 0x10;
const CODEC_LZ4: u8 = 1 << 5;
const HEADER: usize = 16;
/// Below this many bytes c-blosc stores the input as is.
const MIN_BUFFERSIZE: usize = 128;
const MAX_SPLITS: usize = 16;

/// Byte shuffle: byte j of element i goes to `j * n + i` (a trailing partial element is copied).
fn shuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let n = src.len() / typesize;
    if typesize == 4 {
        let (d0, rest) = dst.split_at_mut(n);
        let (d1, rest) = rest.split_at_mut(n);
        let (d2, rest) = rest.split_at_mut(n);
        let (d3, tail) = rest.split_at_mut(n);
        for (i, e) in src.chunks_exact(4).enumerate() {
            d0[i] = e[0];
            d1[i] = e[1];
            d2[i] = e[2];
            d3[i] = e[3];
        }
        tail.copy_from_slice(&src[n * 4..]);
        return;
    }
    for (i, e) in src.chunks_exact(typesize).enumerate() {
        for (j, b) in e.iter().enumerate() {
            dst[j * n + i] = *b;
        }
    }
    dst[n * typesize..].copy_from_slice(&src[n * typesize..]);
}

fn unshuffle(typesize: usize, src: &[u8], dst: &mut [u8]) {
    let n = src.len() / typesize;
    for (i, e) in dst.chunks_exact_mut(typesize).enumerate() {
        for (j, b) in e.iter_mut().enumerate() {
            *b = src[j * n + i];
        }
    }
    dst[n * typesize..].copy_from_slice(&src[n * typesize..]);
}

fn header(flags: u8, typesize: usize, nbytes: usize, blocksize: usize, cbytes: usize) -> [u8; 16] {
    let mut h = [0u8; HEADER];
    h[0] = VERSION_FORMAT;
    h[1] = VERSION_LZ4;
    h[2] = flags;
    h[3] = typesize as u8;
    h[4..8].copy_from_slice(&(nbytes as u32).to_le_bytes());
    h[8..12].copy_from_slice(&(blocksize as u32).to_le_bytes());
    h[12..16].copy_from_slice(&(cbytes as u32).to_le_bytes());
    h
}

fn push_memcpy(out: &mut Vec<u8>, typesize: usize, src: &[u8]) {
    let n = src.len();
    // c-blosc's block size for tiny inputs: 1 below one element, else whole elements.
    let bs = if n < typesize {
        1
    } else {
        n / typesize * typesize
    };
    let flags = FLAG_SHUFFLE | FLAG_MEMCPYED | FLAG_NOSPLIT | CODEC_LZ4;
    out.extend_from_slice(&header(flags, typesize, n, bs, n + HEADER));
    out.extend_from_slice(src);
}

/// Appends a blosc1 frame of `src` (one block, LZ4, byte shuffle) to `out` and returns its
/// length. `typesize` must be 1..=255 and `src.len()` a multiple of it and below 2 GiB.
/// Falls back to a stored frame when LZ4 does not shrink the data, as c-blosc does.
pub fn compress(src: &[u8], typesize: usize, out: &mut Vec<u8>) -> usize {
    let start = out.len();
    let n = src.len();
    if n < MIN_BUFFERSIZE || typesize == 0 || !n.is_multiple_of(typesize) {
        push_memcpy(out, typesize.max(1), src);
        return out.len() - start;
    }
    let split = typesize <= MAX_SPLITS && n / typesize >= MIN_BUFFERSIZE;
    let nsplits = if split { typesize } else { 1 };
    let neblock = n / nsplits;
    let mut shuffled = vec![0u8; n];
    shuffle(typesize, src, &mut shuffled);
    let mut flags = FLAG_SHUFFLE | CODEC_LZ4;
    if !split {
        flags |= FLAG_NOSPLIT;
    }
    out.extend_from_slice(&header(flags, typesize, n, n, 0));
    out.extend_from_slice(&((HEADER + 4) as i32).to_le_bytes());
    let max = lz4_flex::block::get_maximum_output_size(neblock);
    let limit = n + HEADER;
    for stream in shuffled.chunks_exact(neblock) {
        let at = out.len();
        out.resize(at + 4 + max, 0);
        let csize = match lz4_flex::block::compress_into(stream, &mut out[at + 4..]) {
            Ok(c) if c < neblock => c,
            _ => {
                out[at + 4..at + 4 + neblock].copy_from_slice(stream);
                neblock
            }
        };
        out.truncate(at + 4 + csize);
        out[at..at + 4].copy_from_slice(&(csize as i32).to_le_bytes());
        if out.len() - start > limit {
            // Does not fit in the input size + header: store it (c-blosc's last resort).
            out.truncate(start);
            push_memcpy(out, typesize, src);
            return out.len() - start;
        }
    }
    let cbytes = out.len() - start;
    out[start + 12..start + 16].copy_from_slice(&(cbytes as u32).to_le_bytes());
    cbytes
}

fn bad(msg: &str) -> Error {
    Error::InvalidInput(format!("blosc: {msg}"))
}

fn rd_u32(b: &[u8], at: usize) -> Result<usize> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes(s.try_into().unwrap()) as usize)
        .ok_or_else(|| bad("truncated frame"))
}

/// Decompresses one blosc1 frame (LZ4 or stored) into exactly `expected` bytes.
pub fn decompress(frame: &[u8], expected: usize) -> Result<Vec<u8>> {
    if frame.len() < HEADER {
        return Err(bad("truncated header"));
    }
    let flags = frame[2];
    let typesize = frame[3] as usize;
    let nbytes = rd_u32(frame, 4)?;
    let blocksize = rd_u32(frame, 8)?;
    let cbytes = rd_u32(frame, 12)?;
    if frame[0] == 0 || frame[0] > VERSION_FORMAT {
        return Err(bad("unknown format version"));
    }
    if nbytes != expected {
        return Err(bad(&format!("holds {nbytes} bytes, expected {expected}")));
    }
    if cbytes != frame.len() {
        return Err(bad("frame size does not match its header"));
    }
    if flags & FLAG_MEMCPYED != 0 {
        return frame
            .get(HEADER..HEADER + nbytes)
            .map(|s| s.to_vec())
            .ok_or_else(|| bad("truncated stored data"));
    }
    if flags >> 5 != CODEC_LZ4 >> 5 {
        return Err(bad("codec other than LZ4"));
    }
    if flags & FLAG_BITSHUFFLE != 0 {
        return Err(bad("bit shuffle is not supported"));
    }
    if typesize == 0 || blocksize == 0 || blocksize > nbytes.max(1) {
        return Err(bad("bad type or block size"));
    }
    let mut out = vec![0u8; nbytes];
    let nblocks = nbytes.div_ceil(blocksize);
    let mut tmp = vec![0u8; blocksize];
    for b in 0..nblocks {
        let bstart = rd_u32(frame, HEADER + 4 * b)?;
        let lo = b * blocksize;
        let bsize = blocksize.min(nbytes - lo);
        let leftover = bsize < blocksize;
        let nsplits = if flags & FLAG_NOSPLIT == 0 && !leftover && bsize.is_multiple_of(typesize) {
            typesize
        } else {
            1
        };
        let neblock = bsize / nsplits;
        let mut at = bstart;
        for s in 0..nsplits {
            let csize = rd_u32(frame, at)?;
            at += 4;
            let data = frame
                .get(at..at + csize)
                .ok_or_else(|| bad("truncated stream"))?;
            let dst = &mut tmp[s * neblock..(s + 1) * neblock];
            if csize == neblock {
                dst.copy_from_slice(data);
            } else {
                let got = lz4_flex::block::decompress_into(data, dst)
                    .map_err(|e| bad(&format!("LZ4: {e}")))?;
                if got != neblock {
                    return Err(bad("stream decompressed to the wrong size"));
                }
            }
            at += csize;
        }
        let dst = &mut out[lo..lo + bsize];
        if flags & FLAG_SHUFFLE != 0 && typesize > 1 {
            unshuffle(typesize, &tmp[..bsize], dst);
        } else {
            dst.copy_from_slice(&tmp[..bsize]);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(n: usize, typesize: usize) -> Vec<u8> {
        (0..n)
            .map(|i| if i % typesize == 0 { (i / 7) as u8 } else { 3 })
            .collect()
    }

    #[test]
    fn round_trips_all_sizes_and_type_sizes() {
        for ts in [2usize, 4] {
            for n in [0usize, 2, 4, 124, 128, 132, 256, 400, 512, 1000, 2048, 6144] {
                let src = data(n, ts);
                let mut out = Vec::new();
                let c = compress(&src, ts, &mut out);
                assert_eq!(c, out.len());
                assert!(c <= n + HEADER);
                assert_eq!(decompress(&out, n).unwrap(), src, "n={n} ts={ts}");
            }
        }
    }

    #[test]
    fn layout_matches_c_blosc() {
        // Headers as c-blosc 1.21.3 writes them for clevel 9, shuffle, typesize 4, LZ4.
        let mut out = Vec::new();
        compress(&[], 4, &mut out);
        assert_eq!(out, header(0x33, 4, 0, 1, 16));
        let src = data(2048, 4);
        out.clear();
        compress(&src, 4, &mut out);
        assert_eq!(out[..4], [2, 1, 0x21, 4]);
        assert_eq!(rd_u32(&out, 16).unwrap(), 20);
        let src = data(400, 4);
        out.clear();
        compress(&src, 4, &mut out);
        assert_eq!(out[2], 0x31, "100 elements: no split");
    }

    #[test]
    fn rejects_corruption_without_panicking() {
        let src = data(2048, 4);
        let mut out = Vec::new();
        compress(&src, 4, &mut out);
        for cut in 0..out.len() {
            assert!(decompress(&out[..cut], 2048).is_err());
        }
        for i in 0..out.len() {
            let mut b = out.clone();
            b[i] ^= 0x5a;
            let _ = decompress(&b, 2048);
        }
        assert!(decompress(&out, 1024).is_err());
    }
}
