//! Preview render time of a procedural cumulus in a `dim`^3 grid.
use super::splat::Mix;
use crate::error::{Error, Result};
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use crate::preview::{auto_camera, render, PreviewParams};
use std::time::Instant;

/// A cumulus-like density: a union of smooth blobs on a flat base, inside a `dim`^3 voxel box
/// (voxel 1 m). Deterministic.
pub fn cumulus_grid(dim: u32) -> SparseGrid<f32> {
    let n = dim as f64;
    let mut rng = Mix(7);
    let blobs: Vec<([f64; 3], f64)> = (0..24)
        .map(|_| {
            let r = n * (0.08 + 0.10 * rng.next_f64());
            let c = [
                n * (0.25 + 0.5 * rng.next_f64()),
                n * 0.3 + r * 0.8 + n * 0.25 * rng.next_f64(),
                n * (0.25 + 0.5 * rng.next_f64()),
            ];
            (c, r)
        })
        .collect();
    let dens = |p: [f64; 3]| -> f32 {
        let mut s = 0.0;
        for (c, r) in &blobs {
            let d2 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f64>() / (r * r);
            if d2 < 1.0 {
                s += (1.0 - d2).powi(2);
            }
        }
        // Flat cloud base.
        if p[1] < n * 0.3 {
            s *= ((p[1] - n * 0.25) / (n * 0.05)).clamp(0.0, 1.0);
        }
        s.min(1.0) as f32
    };
    let leaves_per_axis = dim.div_ceil(8) as i32;
    let mut leaves = Vec::new();
    for x in 0..leaves_per_axis {
        for y in 0..leaves_per_axis {
            for z in 0..leaves_per_axis {
                let mut values = Box::new([0.0f32; LEAF_VOXELS]);
                let mut mask = [0u64; 8];
                for m in 0..LEAF_VOXELS {
                    let v = [
                        x * 8 + (m as i32 >> 6),
                        y * 8 + ((m as i32 >> 3) & 7),
                        z * 8 + (m as i32 & 7),
                    ];
                    if v.iter().any(|&c| c >= dim as i32) {
                        continue;
                    }
                    let d = dens(v.map(|c| c as f64));
                    if d > 1e-4 {
                        values[m] = d;
                        mask[m / 64] |= 1 << (m % 64);
                    }
                }
                if mask.iter().any(|&w| w != 0) {
                    leaves.push(Leaf {
                        origin: [x * 8, y * 8, z * 8],
                        values,
                        mask,
                    });
                }
            }
        }
    }
    SparseGrid {
        name: "density".into(),
        background: 0.0,
        transform: GridTransform {
            voxel_size: 1.0,
            origin: [0.5; 3],
        },
        leaves,
    }
}

/// Renders a `width`x`height` preview of `cumulus_grid(dim)` (auto-framed, default light,
/// density scale 0.2 /m) in a pool of `threads`; best of three.
pub fn bench_preview(
    width: u32,
    height: u32,
    dim: u32,
    threads: usize,
) -> Result<serde_json::Value> {
    if dim == 0 || threads == 0 {
        return Err(Error::InvalidInput(
            "bench preview: dim and threads must be > 0".into(),
        ));
    }
    let t = Instant::now();
    let grid = cumulus_grid(dim);
    let build = t.elapsed().as_secs_f64();
    let size = [dim as f64; 3];
    let mut params = PreviewParams::defaults(
        auto_camera(size, width as f64 / height as f64, 45.0),
        width,
        height,
    );
    params.density_scale = 0.2;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Runtime(format!("thread pool: {e}")))?;
    let mut best = f64::INFINITY;
    let mut best_cpu = f64::INFINITY;
    for _ in 0..3 {
        let c = super::process_cpu_seconds();
        let t = Instant::now();
        pool.install(|| render(&grid, &params))?;
        best = best.min(t.elapsed().as_secs_f64());
        if let (Some(a), Some(b)) = (c, super::process_cpu_seconds()) {
            best_cpu = best_cpu.min(b - a);
        }
    }
    Ok(serde_json::json!({
        "width": width,
        "height": height,
        "grid_dim": dim,
        "leaves": grid.leaves.len(),
        "active_voxels": grid.active_voxel_count(),
        "threads": threads,
        "grid_build_s": build,
        "render_s": best,
        "render_cpu_s": best_cpu.is_finite().then_some(best_cpu),
    }))
}
