//! Figures of a cloud's surface from its density grid (`nimbus bench detail`, `nimbus bench
//! look`; docs/RENDERING.md "Detail at the surface"):
//! - the boundary: the iso-surface of the undetailed density at `tau` (`boundary_level`), and
//!   each voxel's signed distance to it (exact Euclidean distance transform, positive inside);
//! - the RMS change from the undetailed density inside the cloud, more than a given distance
//!   from the boundary, relative to the undetailed RMS there;
//! - the energy below the particle wavelength in the shell within a given distance of the
//!   boundary: the density high-passed at |k| > 1 / wavelength (a sharp cut of its 3-D FFT),
//!   squared and summed over the shell's voxels;
//! - the boundary's 10%-90% thickness along the density gradient: from each surface voxel of a
//!   grid (at or above `tau`, a face neighbour below), the grid sampled along its gradient
//!   across the shell (`shell` either side); the distance over which it rises from 10% to 90%
//!   of its largest value on the inward side.
use crate::ground::SparseGrid;

/// A grid copied into a dense box: the union of the grids' active boxes, grown by `pad` voxels.
#[derive(Debug, Clone)]
pub struct Dense {
    pub lo: [i32; 3],
    pub dims: [usize; 3],
    pub values: Vec<f64>,
    /// Voxel edge (m).
    pub voxel: f64,
}

impl Dense {
    /// The boxes of `grids` (one transform) as dense arrays over one common box.
    pub fn common(grids: &[&SparseGrid<f32>], pad: i32) -> Option<Vec<Dense>> {
        let mut lo = [i32::MAX; 3];
        let mut hi = [i32::MIN; 3];
        for g in grids {
            if let Some((a, b)) = g.active_bbox() {
                for k in 0..3 {
                    lo[k] = lo[k].min(a[k] - pad);
                    hi[k] = hi[k].max(b[k] + pad);
                }
            }
        }
        if lo[0] > hi[0] {
            return None;
        }
        let dims = [0, 1, 2].map(|k| (hi[k] - lo[k] + 1) as usize);
        Some(
            grids
                .iter()
                .map(|g| {
                    let mut values = vec![0.0; dims[0] * dims[1] * dims[2]];
                    for l in &g.leaves {
                        for n in 0..512 {
                            if l.is_active(n) {
                                let p = [
                                    l.origin[0] + (n >> 6) as i32 - lo[0],
                                    l.origin[1] + ((n >> 3) & 7) as i32 - lo[1],
                                    l.origin[2] + (n & 7) as i32 - lo[2],
                                ];
                                values[(p[0] as usize * dims[1] + p[1] as usize) * dims[2]
                                    + p[2] as usize] = l.values[n] as f64;
                            }
                        }
                    }
                    Dense {
                        lo,
                        dims,
                        values,
                        voxel: g.transform.voxel_size,
                    }
                })
                .collect(),
        )
    }

    #[inline]
    pub fn idx(&self, x: usize, y: usize, z: usize) -> usize {
        (x * self.dims[1] + y) * self.dims[2] + z
    }

    /// Value at integer coordinates of the box, 0 outside it.
    #[inline]
    pub fn at(&self, p: [i64; 3]) -> f64 {
        if (0..3).any(|k| p[k] < 0 || p[k] >= self.dims[k] as i64) {
            return 0.0;
        }
        self.values[self.idx(p[0] as usize, p[1] as usize, p[2] as usize)]
    }

    /// Trilinear value at box coordinates `q` (voxel units).
    pub fn sample(&self, q: [f64; 3]) -> f64 {
        let mut s = 0.0;
        for (i, w) in trilinear_corners(q) {
            if w > 0.0 {
                s += w * self.at(i);
            }
        }
        s
    }

    /// Central-difference gradient at a voxel (per voxel).
    pub fn gradient(&self, p: [i64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| {
            let mut u = p;
            let mut d = p;
            u[a] += 1;
            d[a] -= 1;
            0.5 * (self.at(u) - self.at(d))
        })
    }
}

/// Signed distance (voxels) from every voxel to the boundary of `inside`: positive inside,
/// the distance to the nearest voxel outside; negative outside, minus the distance to the
/// nearest voxel inside. Exact Euclidean (Felzenszwalb & Huttenlocher's separable transform).
pub fn signed_distance(inside: &[bool], dims: [usize; 3]) -> Vec<f64> {
    let to_in = edt(inside, dims, true);
    let to_out = edt(inside, dims, false);
    inside
        .iter()
        .zip(to_in.iter().zip(&to_out))
        .map(|(&i, (&a, &b))| if i { b.sqrt() } else { -a.sqrt() })
        .collect()
}

/// Squared distance of every voxel to the nearest voxel where `mask == target`.
fn edt(mask: &[bool], dims: [usize; 3], target: bool) -> Vec<f64> {
    const FAR: f64 = 1.0e20;
    let mut d: Vec<f64> = mask
        .iter()
        .map(|&m| if m == target { 0.0 } else { FAR })
        .collect();
    let idx = |c: [usize; 3]| (c[0] * dims[1] + c[1]) * dims[2] + c[2];
    let mut f = Vec::new();
    let mut out = Vec::new();
    for axis in 0..3 {
        let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
        for i in 0..dims[a1] {
            for j in 0..dims[a2] {
                f.clear();
                for k in 0..dims[axis] {
                    let mut c = [0; 3];
                    c[axis] = k;
                    c[a1] = i;
                    c[a2] = j;
                    f.push(d[idx(c)]);
                }
                edt_1d(&f, &mut out);
                for (k, v) in out.iter().enumerate() {
                    let mut c = [0; 3];
                    c[axis] = k;
                    c[a1] = i;
                    c[a2] = j;
                    d[idx(c)] = *v;
                }
            }
        }
    }
    d
}

/// The 1-D squared distance transform of sampled function `f` (lower envelope of parabolas).
fn edt_1d(f: &[f64], out: &mut Vec<f64>) {
    let n = f.len();
    out.clear();
    out.resize(n, 0.0);
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let mut k = 0usize;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in 1..n {
        loop {
            let p = v[k];
            let s = ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64);
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                // k == 0 and the new parabola wins everywhere
                v[0] = q;
                z[1] = f64::INFINITY;
                break;
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
            break;
        }
    }
    let mut k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        let dq = q as f64 - p as f64;
        *o = dq * dq + f[p];
    }
}

/// The field high-passed at |k| > 1 / `wavelength` (m): a sharp cut of its 3-D FFT (the box
/// zero-padded to powers of two), back in space, over the box.
pub fn high_pass(g: &Dense, wavelength: f64) -> Vec<f64> {
    let dims = g.dims.map(|n| n.next_power_of_two());
    let [nx, ny, nz] = dims;
    let idx = |x: usize, y: usize, z: usize| (x * ny + y) * nz + z;
    let mut re = vec![0.0f64; nx * ny * nz];
    let mut im = vec![0.0f64; nx * ny * nz];
    for x in 0..g.dims[0] {
        for y in 0..g.dims[1] {
            for z in 0..g.dims[2] {
                re[idx(x, y, z)] = g.values[g.idx(x, y, z)];
            }
        }
    }
    fft3(&mut re, &mut im, dims, false);
    let kmin = 1.0 / wavelength;
    let freq = |k: usize, n: usize| {
        let k = if k > n / 2 {
            k as f64 - n as f64
        } else {
            k as f64
        };
        k / (n as f64 * g.voxel)
    };
    for x in 0..nx {
        for y in 0..ny {
            for z in 0..nz {
                let f = [freq(x, nx), freq(y, ny), freq(z, nz)];
                if (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() <= kmin {
                    re[idx(x, y, z)] = 0.0;
                    im[idx(x, y, z)] = 0.0;
                }
            }
        }
    }
    fft3(&mut re, &mut im, dims, true);
    let mut out = vec![0.0; g.values.len()];
    for x in 0..g.dims[0] {
        for y in 0..g.dims[1] {
            for z in 0..g.dims[2] {
                out[g.idx(x, y, z)] = re[idx(x, y, z)];
            }
        }
    }
    out
}

/// The 8 corners of the voxel cell holding `q` (index units) and their trilinear weights, corner
/// c = (c >> 2 & 1, c >> 1 & 1, c & 1) from the floor of `q`, in that order.
pub fn trilinear_corners(q: [f64; 3]) -> impl Iterator<Item = ([i64; 3], f64)> {
    let b = q.map(|v| v.floor());
    let t = [0, 1, 2].map(|a| q[a] - b[a]);
    (0..8).map(move |c: usize| {
        let o = [c >> 2 & 1, c >> 1 & 1, c & 1];
        let w: f64 = (0..3)
            .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
            .product();
        ([0, 1, 2].map(|a| b[a] as i64 + o[a] as i64), w)
    })
}

/// 3-D FFT (or its inverse, normalised) of a box whose sides are powers of two.
pub fn fft3(re: &mut [f64], im: &mut [f64], dims: [usize; 3], inverse: bool) {
    let idx = |c: [usize; 3]| (c[0] * dims[1] + c[1]) * dims[2] + c[2];
    if inverse {
        im.iter_mut().for_each(|v| *v = -*v);
    }
    let mut line_re = Vec::new();
    let mut line_im = Vec::new();
    for axis in 0..3 {
        let n = dims[axis];
        for i in 0..dims[(axis + 1) % 3] {
            for j in 0..dims[(axis + 2) % 3] {
                let at = |k: usize| {
                    let mut c = [0usize; 3];
                    c[axis] = k;
                    c[(axis + 1) % 3] = i;
                    c[(axis + 2) % 3] = j;
                    idx(c)
                };
                line_re.clear();
                line_im.clear();
                for k in 0..n {
                    line_re.push(re[at(k)]);
                    line_im.push(im[at(k)]);
                }
                fft(&mut line_re, &mut line_im);
                for k in 0..n {
                    re[at(k)] = line_re[k];
                    im[at(k)] = line_im[k];
                }
            }
        }
    }
    if inverse {
        let s = 1.0 / re.len() as f64;
        re.iter_mut().for_each(|v| *v *= s);
        im.iter_mut().for_each(|v| *v *= -s);
    }
}

/// In-place radix-2 FFT (length a power of two).
pub fn fft(re: &mut [f64], im: &mut [f64]) {
    let n = re.len();
    if n < 2 {
        return;
    }
    let mut j = 0;
    for i in 1..n {
        let mut bit = n >> 1;
        while j & bit != 0 {
            j ^= bit;
            bit >>= 1;
        }
        j |= bit;
        if i < j {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut len = 2;
    while len <= n {
        let ang = -2.0 * std::f64::consts::PI / len as f64;
        for start in (0..n).step_by(len) {
            for k in 0..len / 2 {
                let (s, c) = (ang * k as f64).sin_cos();
                let a = start + k;
                let b = a + len / 2;
                let tr = re[b] * c - im[b] * s;
                let ti = re[b] * s + im[b] * c;
                re[b] = re[a] - tr;
                im[b] = im[a] - ti;
                re[a] += tr;
                im[a] += ti;
            }
        }
        len <<= 1;
    }
}

/// 10%-90% rise distances (voxels) along the density gradient from every surface voxel of `g`
/// at level `tau`: the grid sampled every quarter voxel from `reach` voxels outside to `reach`
/// inside; 90% of the largest value on the inward half, the first point reaching it, and the
/// last point at or below 10% before that.
pub fn boundary_thickness(g: &Dense, tau: f64, reach: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let step = 0.25;
    let n = (reach / step).ceil() as i64;
    for x in 0..g.dims[0] {
        for y in 0..g.dims[1] {
            for z in 0..g.dims[2] {
                let p = [x as i64, y as i64, z as i64];
                if g.at(p) < tau {
                    continue;
                }
                let surface = (0..3).any(|a| {
                    [-1i64, 1].iter().any(|&d| {
                        let mut q = p;
                        q[a] += d;
                        g.at(q) < tau
                    })
                });
                if !surface {
                    continue;
                }
                let gr = g.gradient(p);
                let gn = (gr[0] * gr[0] + gr[1] * gr[1] + gr[2] * gr[2]).sqrt();
                if gn <= 0.0 {
                    continue;
                }
                let u = gr.map(|v| v / gn);
                let profile: Vec<f64> = (-n..=n)
                    .map(|i| {
                        let s = i as f64 * step;
                        g.sample([0, 1, 2].map(|a| p[a] as f64 + s * u[a]))
                    })
                    .collect();
                let top = profile[n as usize..].iter().copied().fold(0.0f64, f64::max);
                let Some(i90) = profile.iter().position(|&v| v >= 0.9 * top) else {
                    continue;
                };
                let Some(i10) = profile[..=i90].iter().rposition(|&v| v <= 0.1 * top) else {
                    continue;
                };
                out.push((i90 - i10) as f64 * step);
            }
        }
    }
    out
}

/// The figures of item 2 of docs/RENDERING.md "Detail at the surface" for an undetailed grid
/// `d0` and a detailed one `d1` (same transform): boundary at level `tau` of `d0`; `inside`
/// and `shell` distances and the wavelength in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceFigures {
    /// RMS(d1 - d0) / RMS(d0) over the voxels more than `inside` from the boundary.
    pub inside_rms_change: f64,
    pub inside_voxels: usize,
    /// Energy of the high-passed density in the shell, detailed over undetailed.
    pub shell_energy_ratio: f64,
    pub shell_voxels: usize,
    /// 10%-90% thickness (voxels) of each grid's boundary, across the shell: the quartiles.
    pub thickness_undetailed: [f64; 3],
    pub thickness_detailed: [f64; 3],
}

pub fn surface_figures(
    d0: &SparseGrid<f32>,
    d1: &SparseGrid<f32>,
    tau: f64,
    inside: f64,
    shell: f64,
    wavelength: f64,
) -> Option<SurfaceFigures> {
    let v = d0.transform.voxel_size;
    let pad = ((inside.max(shell).max(wavelength)) / v).ceil() as i32 + 2;
    let boxes = Dense::common(&[d0, d1], pad)?;
    let (a, b) = (&boxes[0], &boxes[1]);
    let mask: Vec<bool> = a.values.iter().map(|&x| x >= tau).collect();
    let sd = signed_distance(&mask, a.dims);
    let (mut num, mut den, mut n_in) = (0.0, 0.0, 0usize);
    for (i, &di) in sd.iter().enumerate() {
        if di * v > inside {
            let d = b.values[i] - a.values[i];
            num += d * d;
            den += a.values[i] * a.values[i];
            n_in += 1;
        }
    }
    let ha = high_pass(a, wavelength);
    let hb = high_pass(b, wavelength);
    let (mut ea, mut eb, mut n_sh) = (0.0, 0.0, 0usize);
    for (i, &di) in sd.iter().enumerate() {
        if di.abs() * v <= shell {
            ea += ha[i] * ha[i];
            eb += hb[i] * hb[i];
            n_sh += 1;
        }
    }
    let reach = shell / v;
    let quartiles = |mut t: Vec<f64>| {
        if t.is_empty() {
            return [f64::NAN; 3];
        }
        t.sort_by(f64::total_cmp);
        [0.25, 0.5, 0.75].map(|q| t[((t.len() - 1) as f64 * q).round() as usize])
    };
    Some(SurfaceFigures {
        inside_rms_change: if den > 0.0 {
            (num / den).sqrt()
        } else {
            f64::NAN
        },
        inside_voxels: n_in,
        shell_energy_ratio: if ea > 0.0 { eb / ea } else { f64::NAN },
        shell_voxels: n_sh,
        thickness_undetailed: quartiles(boundary_thickness(a, tau, reach)),
        thickness_detailed: quartiles(boundary_thickness(b, tau, reach)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_transform_is_euclidean_and_signed() {
        let dims = [21, 21, 21];
        let inside: Vec<bool> = (0..21 * 21 * 21)
            .map(|i| {
                let (x, y, z) = (i / 441, (i / 21) % 21, i % 21);
                (5..16).contains(&x) && (5..16).contains(&y) && (5..16).contains(&z)
            })
            .collect();
        let sd = signed_distance(&inside, dims);
        let at = |x: usize, y: usize, z: usize| sd[(x * 21 + y) * 21 + z];
        // centre of the 11-voxel cube: 6 voxels to the nearest outside voxel
        assert_eq!(at(10, 10, 10), 6.0);
        assert_eq!(at(5, 10, 10), 1.0);
        assert_eq!(at(4, 10, 10), -1.0);
        // off a corner: the diagonal distance to the corner voxel (5, 5, 5)
        assert!((at(2, 2, 2) + (27.0f64).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn high_pass_keeps_short_waves_and_drops_long_ones() {
        let n = 32;
        let mk = |wl: f64| Dense {
            lo: [0; 3],
            dims: [n, n, n],
            values: (0..n * n * n)
                .map(|i| (2.0 * std::f64::consts::PI * (i / (n * n)) as f64 * 10.0 / wl).sin())
                .collect(),
            voxel: 10.0,
        };
        // 80 m waves on 10 m voxels: below a 50 m cut nothing; 40 m waves pass whole
        let e = |g: &Dense| high_pass(g, 50.0).iter().map(|v| v * v).sum::<f64>();
        let total = |g: &Dense| g.values.iter().map(|v| v * v).sum::<f64>();
        let (long, short) = (mk(80.0), mk(40.0));
        assert!(e(&long) < 1e-9 * total(&long));
        assert!((e(&short) / total(&short) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn thickness_tells_a_step_from_a_ramp() {
        let n = 40;
        let mk = |width: f64| Dense {
            lo: [0; 3],
            dims: [n, n, n],
            // a ball of radius 13 voxels, its boundary rising over `width` voxels
            values: (0..n * n * n)
                .map(|i| {
                    let p = [i / (n * n), (i / n) % n, i % n].map(|v| v as f64 - 20.0);
                    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                    ((13.0 - r) / width + 0.5).clamp(0.0, 1.0)
                })
                .collect(),
            voxel: 12.5,
        };
        let med = |g: &Dense| {
            let mut t = boundary_thickness(g, 0.3, 12.0);
            t.sort_by(f64::total_cmp);
            t[t.len() / 2]
        };
        // a linear ramp over w voxels rises from 10% to 90% over 0.8 w
        assert!((med(&mk(10.0)) - 8.0).abs() <= 0.5, "{}", med(&mk(10.0)));
        assert!(med(&mk(1.0)) <= 2.0, "{}", med(&mk(1.0)));
    }
}
