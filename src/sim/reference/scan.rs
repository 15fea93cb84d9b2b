//! Mirror of shaders/scan.wgsl (`scan_reduce`, `scan_blocks`): the exclusive u32 prefix scan,
//! reduce-then-scan in blocks of `SCAN_BLOCK` (2048), composed over levels as the GPU's
//! `PrefixScan` runs them. A nonzero `mask` scans `(v & mask) != 0` as 0/1 instead of the values
//! (the adaptive stage's flag scans).
pub const BLOCK: usize = crate::gpu::shaders::SCAN_BLOCK as usize;

/// The value a scan with `mask` adds for `v`.
pub fn masked(v: u32, mask: u32) -> u32 {
    if mask == 0 {
        v
    } else {
        (v & mask != 0) as u32
    }
}

/// The total of each block of `BLOCK` (of the masked values).
pub fn scan_reduce(data: &[u32], mask: u32) -> Vec<u32> {
    data.chunks(BLOCK)
        .map(|b| b.iter().fold(0u32, |s, &v| s.wrapping_add(masked(v, mask))))
        .collect()
}

/// Exclusive scan of each block in place, block g starting from `offsets[g]` (from 0 without).
pub fn scan_blocks(data: &mut [u32], mask: u32, offsets: Option<&[u32]>) {
    for (g, b) in data.chunks_mut(BLOCK).enumerate() {
        let mut s = offsets.map_or(0, |o| o[g]);
        for v in b.iter_mut() {
            let x = masked(*v, mask);
            *v = s;
            s = s.wrapping_add(x);
        }
    }
}

/// Multi-level exclusive scan in place: the mask applies to the data, the block totals are
/// scanned as values.
pub fn prefix_scan(data: &mut [u32], mask: u32) {
    if data.len() <= BLOCK {
        scan_blocks(data, mask, None);
        return;
    }
    let mut totals = scan_reduce(data, mask);
    prefix_scan(&mut totals, 0);
    scan_blocks(data, mask, Some(&totals));
}

/// Exclusive scan of the first `n` values (mask 0) or of `(v & mask) != 0`.
pub fn exclusive_scan(values: &[u32], n: usize, mask: u32) -> Vec<u32> {
    let mut out = values[..n].to_vec();
    prefix_scan(&mut out, mask);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three levels (more than `BLOCK`^2 values), against a running sum, with and without a mask.
    #[test]
    fn exclusive_scan_is_the_running_sum() {
        let big = BLOCK * BLOCK + 5;
        let values: Vec<u32> = (0..big as u32)
            .map(|i| i.wrapping_mul(2654435761) >> 26)
            .collect();
        for (n, mask) in [
            (big, 0),
            (big, 0b1010),
            (BLOCK + 1, 0),
            (BLOCK, 4),
            (257, 0),
            (256, 4),
            (1, 0),
            (0, 0),
        ] {
            let mut acc = 0u32;
            let expect: Vec<u32> = values[..n]
                .iter()
                .map(|&v| {
                    let e = acc;
                    acc += if mask == 0 { v } else { (v & mask != 0) as u32 };
                    e
                })
                .collect();
            assert_eq!(
                exclusive_scan(&values, n, mask),
                expect,
                "n {n} mask {mask}"
            );
        }
    }
}
