//! Mirror of shaders/scan.wgsl (`scan_blocks`, `scan_add`): the exclusive u32 prefix scan in
//! blocks of `SCAN_BLOCK` (2048), composed over levels as the GPU's `PrefixScan`
//! runs them. A nonzero `mask` scans `(v & mask) != 0` as 0/1 instead of the values (the
//! adaptive stage's flag scans).
pub const BLOCK: usize = crate::gpu::shaders::SCAN_BLOCK as usize;

/// The value a scan with `mask` adds for `v`.
pub fn masked(v: u32, mask: u32) -> u32 {
    if mask == 0 {
        v
    } else {
        (v & mask != 0) as u32
    }
}

/// Exclusive scan of each block of `BLOCK` (of the masked values) in place; returns the block
/// sums.
pub fn scan_blocks(data: &mut [u32], mask: u32) -> Vec<u32> {
    data.chunks_mut(BLOCK)
        .map(|b| {
            let mut s = 0u32;
            for v in b.iter_mut() {
                let x = masked(*v, mask);
                *v = s;
                s = s.wrapping_add(x);
            }
            s
        })
        .collect()
}

/// Adds the scanned block sums back to each block.
pub fn scan_add(data: &mut [u32], sums: &[u32]) {
    for (b, s) in data.chunks_mut(BLOCK).zip(sums) {
        for v in b {
            *v = v.wrapping_add(*s);
        }
    }
}

/// Multi-level exclusive scan in place: the mask applies to the data, the block sums are
/// scanned as values.
pub fn prefix_scan(data: &mut [u32], mask: u32) {
    let mut sums = scan_blocks(data, mask);
    if sums.len() > 1 {
        prefix_scan(&mut sums, 0);
        scan_add(data, &sums);
    }
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
