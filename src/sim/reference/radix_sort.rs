//! Mirror of shaders/radix_sort.wgsl (`radix_count`, `radix_scatter`), composed with the
//! [`scan`](super::scan) mirror into the whole sort as `gpu::sort::RadixSort` runs it.
use super::scan::{prefix_scan, BLOCK};

/// Digit histogram per tile of 256, digit-major.
pub fn radix_count(keys: &[u32], shift: u32) -> Vec<u32> {
    let tiles = keys.len().div_ceil(BLOCK).max(1);
    let mut hist = vec![0u32; 16 * tiles];
    for (t, tile) in keys.chunks(BLOCK).enumerate() {
        for k in tile {
            hist[((k >> shift) & 15) as usize * tiles + t] += 1;
        }
    }
    hist
}

/// Stable scatter of one pass given the scanned histogram.
pub fn radix_scatter(
    keys: &[u32],
    vals: &[u32],
    shift: u32,
    scanned: &[u32],
) -> (Vec<u32>, Vec<u32>) {
    let tiles = keys.len().div_ceil(BLOCK).max(1);
    let mut ko = vec![0u32; keys.len()];
    let mut vo = vec![0u32; keys.len()];
    for t in 0..tiles {
        let mut seen = [0u32; 16];
        for i in t * BLOCK..((t + 1) * BLOCK).min(keys.len()) {
            let d = ((keys[i] >> shift) & 15) as usize;
            let dst = (scanned[d * tiles + t] + seen[d]) as usize;
            seen[d] += 1;
            ko[dst] = keys[i];
            vo[dst] = vals[i];
        }
    }
    (ko, vo)
}

/// The whole LSD sort over `bits` key bits.
pub fn radix_sort(keys: &[u32], vals: &[u32], bits: u32) -> (Vec<u32>, Vec<u32>) {
    let (mut k, mut v) = (keys.to_vec(), vals.to_vec());
    for p in 0..bits.max(1).div_ceil(4) {
        let mut hist = radix_count(&k, 4 * p);
        prefix_scan(&mut hist, 0);
        (k, v) = radix_scatter(&k, &v, 4 * p, &hist);
    }
    (k, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirror_sort_is_a_stable_sort() {
        let keys: Vec<u32> = (0..5000u32)
            .map(|i| (i.wrapping_mul(2654435761) >> 7) % 300)
            .collect();
        let vals: Vec<u32> = (0..5000).collect();
        let (k, v) = radix_sort(&keys, &vals, 9);
        let mut expect: Vec<u32> = vals.clone();
        expect.sort_by_key(|&i| keys[i as usize]);
        assert_eq!(v, expect);
        assert!(k.windows(2).all(|w| w[0] <= w[1]));
    }
}
