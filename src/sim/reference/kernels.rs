//! f64 mirror of shaders/shared/common.wgsl.
use std::f64::consts::PI;

pub fn poly6(r2: f64, h: f64) -> f64 {
    let h2 = h * h;
    if r2 >= h2 {
        return 0.0;
    }
    let d = h2 - r2;
    315.0 / (64.0 * PI * h.powi(9)) * d * d * d
}

pub fn spiky_grad(xij: [f64; 3], r: f64, h: f64) -> [f64; 3] {
    if r >= h || r <= 1e-9 * h {
        return [0.0; 3];
    }
    let d = h - r;
    let s = -45.0 / (PI * h.powi(6)) * d * d / r;
    [s * xij[0], s * xij[1], s * xij[2]]
}

pub fn poly6_sym(r2: f64, hi: f64, hj: f64) -> f64 {
    0.5 * (poly6(r2, hi) + poly6(r2, hj))
}

pub fn spiky_grad_sym(xij: [f64; 3], r: f64, hi: f64, hj: f64) -> [f64; 3] {
    let a = spiky_grad(xij, r, hi);
    let b = spiky_grad(xij, r, hj);
    [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ]
}

/// Minimum-image displacement; `periodic` = [x, z].
pub fn min_image(d: [f64; 3], size: [f64; 3], periodic: [bool; 2]) -> [f64; 3] {
    let mut r = d;
    if periodic[0] {
        r[0] -= size[0] * (r[0] / size[0]).round();
    }
    if periodic[1] {
        r[2] -= size[2] * (r[2] / size[2]).round();
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Poly6 integrates to 1 over its support (normalisation), checked by a midpoint sum.
    #[test]
    fn poly6_is_normalised() {
        let h = 1.3;
        let n = 60;
        let dx = 2.0 * h / n as f64;
        let mut s = 0.0;
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let p = [i, j, k].map(|v| -h + (v as f64 + 0.5) * dx);
                    s += poly6(p[0] * p[0] + p[1] * p[1] + p[2] * p[2], h) * dx * dx * dx;
                }
            }
        }
        assert!((s - 1.0).abs() < 2e-3, "integral {s}");
    }
}
