//! Mirror of shaders/shared/permute.wgsl (the `permute4`/`permute2` and `copy4`/`copy2` stages).

/// Mirror of `permute4`/`permute2`: `dst[i] = src[order[i]]`.
pub fn permute<T: Copy>(order: &[u32], src: &[T]) -> Vec<T> {
    order.iter().map(|&o| src[o as usize]).collect()
}

/// Mirror of `copy4`/`copy2`: `dst[i] = src[i]` for the first `n`.
pub fn copy<T: Copy>(src: &[T], dst: &mut [T], n: usize) {
    dst[..n].copy_from_slice(&src[..n]);
}
