//! `nimbus bench vdb`: nimbus's VDB writer against OpenVDB's own (`pyopenvdb.write`, run by
//! `tools/bench_openvdb.py` under `/usr/bin/python3`) on the same cloud-like grid and codec.
use crate::config::Compression;
use crate::error::{Error, Result};
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use crate::io::vdb::{self, VdbFile, VdbGrid, VdbOptions};
use rayon::prelude::*;
use serde_json::json;
use std::time::Instant;

const SCRIPT: &str = include_str!("../../tools/bench_openvdb.py");

fn hash3(x: i32, y: i32, z: i32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ (z as u32).wrapping_mul(0xcb1a_b31f);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    (h & 0xffff) as f32 / 65535.0
}

/// Trilinear value noise on a lattice of `cell` voxels, in [0, 1].
fn noise(p: [i32; 3], cell: i32) -> f32 {
    let c = p.map(|v| v.div_euclid(cell));
    let f = p.map(|v| v.rem_euclid(cell) as f32 / cell as f32);
    let mut acc = 0.0;
    for corner in 0..8 {
        let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let w: f32 = (0..3)
            .map(|a| if d[a] == 1 { f[a] } else { 1.0 - f[a] })
            .product();
        acc += w * hash3(c[0] + d[0], c[1] + d[1], c[2] + d[2]);
    }
    acc
}

/// A cloud-like density grid of about `active_voxels` active voxels: a ball whose radius is
/// perturbed by value noise (ragged, partly filled leaves at the edge) with noisy density
/// inside, like a splatted cloud. Deterministic.
pub fn cloud_grid(active_voxels: usize) -> SparseGrid<f32> {
    let r = (3.0 * active_voxels as f64 / (4.0 * std::f64::consts::PI)).cbrt() as f32;
    let reach = (r * 1.3).ceil() as i32 + 8;
    let lo = -(reach & !7) - 8;
    let n = ((2 * reach) / 8 + 2) as usize;
    let origins: Vec<[i32; 3]> = (0..n * n * n)
        .map(|i| {
            [
                lo + 8 * (i / (n * n)) as i32,
                lo + 8 * ((i / n) % n) as i32,
                lo + 8 * (i % n) as i32,
            ]
        })
        .collect();
    let leaves: Vec<Leaf<f32>> = origins
        .par_iter()
        .filter_map(|&o| {
            let mut values = Box::new([0f32; LEAF_VOXELS]);
            let mut mask = [0u64; 8];
            for v in 0..LEAF_VOXELS {
                let p = [
                    o[0] + (v >> 6) as i32,
                    o[1] + ((v >> 3) & 7) as i32,
                    o[2] + (v & 7) as i32,
                ];
                let d = ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) as f32).sqrt();
                let edge = r * (0.8 + 0.4 * noise(p, 16));
                if d < edge {
                    let fall = (1.0 - d / edge).sqrt();
                    values[v] = fall * (0.5 + 0.5 * noise(p, 4)) * 0.8;
                    mask[v / 64] |= 1 << (v % 64);
                }
            }
            mask.iter().any(|&w| w != 0).then_some(Leaf {
                origin: o,
                values,
                mask,
            })
        })
        .collect();
    SparseGrid {
        name: "density".into(),
        background: 0.0,
        transform: GridTransform {
            voxel_size: 10.0,
            origin: [0.0; 3],
        },
        leaves,
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1000.0
}

fn summary(mut v: Vec<f64>) -> serde_json::Value {
    v.sort_by(|a, b| a.total_cmp(b));
    json!({ "min": v[0], "median": v[v.len() / 2], "all": v })
}

/// Times nimbus's writer (in memory, and to a file with fsync + rename) and OpenVDB's writer
/// on the same grid; returns the figures as JSON.
pub fn bench_vdb_write(
    active_voxels: usize,
    compression: Compression,
    reps: usize,
) -> Result<serde_json::Value> {
    let reps = reps.max(1);
    let grid = cloud_grid(active_voxels);
    let active = grid.active_voxel_count();
    let leaves = grid.leaves.len();
    let file = VdbFile {
        grids: vec![VdbGrid::float("density", grid)],
        metadata: VdbFile::standard_metadata(1),
    };
    let opts = VdbOptions {
        compression,
        half: false,
    };
    let dir = std::env::temp_dir().join(format!("nimbus-bench-vdb-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let out = dir.join("nimbus.vdb");
    let mut encode_ms = Vec::new();
    let mut write_ms = Vec::new();
    let mut bytes = 0;
    for _ in 0..reps {
        let t = Instant::now();
        let enc = vdb::encode(&file, &opts)?;
        encode_ms.push(ms(t));
        bytes = enc.len;
        let t = Instant::now();
        vdb::write_file(&out, &file, &opts)?;
        write_ms.push(ms(t));
    }
    // OpenVDB reads the same grid from an uncompressed file and writes it with its default
    // codec (blosc + active mask), the only one pyopenvdb can select.
    let src = dir.join("input.vdb");
    vdb::write_file(
        &src,
        &file,
        &VdbOptions {
            compression: Compression::None,
            half: false,
        },
    )?;
    let script = dir.join("bench_openvdb.py");
    std::fs::write(&script, SCRIPT).map_err(|e| Error::io(&script, e))?;
    let openvdb = if compression != Compression::Blosc {
        json!({ "skipped": "pyopenvdb writes blosc + active mask only" })
    } else {
        match std::process::Command::new("/usr/bin/python3")
            .arg(&script)
            .arg(&src)
            .arg(dir.join("openvdb.vdb"))
            .arg(reps.to_string())
            .output()
        {
            Ok(o) if o.status.success() => serde_json::from_slice::<serde_json::Value>(&o.stdout)
                .map(|mut v| {
                    let t: Vec<f64> = v["write_ms"]
                        .as_array()
                        .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
                        .unwrap_or_default();
                    if !t.is_empty() {
                        v["write_ms"] = summary(t);
                    }
                    v
                })
                .unwrap_or_else(|e| json!({ "skipped": format!("bad output: {e}") })),
            Ok(o) => json!({ "skipped": String::from_utf8_lossy(&o.stderr).trim().to_string() }),
            Err(e) => json!({ "skipped": format!("/usr/bin/python3: {e}") }),
        }
    };
    let _ = std::fs::remove_dir_all(&dir);
    let nimbus = json!({
        "encode_ms": summary(encode_ms.clone()),
        "write_ms": summary(write_ms.clone()),
        "bytes": bytes,
    });
    let mut report = json!({
        "bench": "vdb_write",
        "active_voxels": active,
        "leaves": leaves,
        "compression": format!("{compression:?}").to_lowercase(),
        "threads": rayon::current_num_threads(),
        "reps": reps,
        "nimbus": nimbus,
        "openvdb": openvdb,
    });
    let ov_ms = report["openvdb"]["write_ms"]["min"].as_f64();
    let ov_bytes = report["openvdb"]["bytes"].as_f64();
    if let (Some(o), Some(b)) = (ov_ms, ov_bytes) {
        let e = encode_ms.iter().cloned().fold(f64::INFINITY, f64::min);
        let w = write_ms.iter().cloned().fold(f64::INFINITY, f64::min);
        report["speedup_vs_openvdb"] = json!({ "encode": o / e, "write_fsync": o / w });
        report["size_ratio_vs_openvdb"] = json!(bytes as f64 / b);
    }
    Ok(report)
}
