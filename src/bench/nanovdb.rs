//! `nimbus bench nanovdb`: nimbus's NanoVDB writer against NanoVDB's own converter
//! (`nanovdb_convert -c full`, Debian's `libnanovdb-tools`) on the same grids, side by side in one
//! run, and the file sizes of each precision. The converter reads the grids from an uncompressed
//! VDB file (its cheapest input), so its time is reading + converting + writing into the page
//! cache; nimbus's is encoding (statistics, checksum) and writing from the grids in memory: into
//! the page cache like the converter, and atomically with fsync as a frame is written. On a
//! shared machine the ratios hold better than the times.
use super::vdb::cloud_grid;
use crate::config::Compression;
use crate::error::{Error, Result};
use crate::io::nanovdb::{self, GridClass, NanoGrid, NanoValues, Quantise};
use crate::io::vdb::{self, GridData, VdbFile, VdbGrid, VdbOptions};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What to measure: the grids of a VDB file (e.g. quickstart's last frame), or a synthetic
/// cloud of about `active_voxels` voxels.
pub enum Source {
    File(PathBuf),
    Cloud(usize),
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1000.0
}

fn summary(mut v: Vec<f64>) -> serde_json::Value {
    v.sort_by(|a, b| a.total_cmp(b));
    json!({ "min": v[0], "median": v[v.len() / 2], "all": v })
}

fn min(v: &[f64]) -> f64 {
    v.iter().cloned().fold(f64::INFINITY, f64::min)
}

/// The NanoVDB grids of `file`, float grids stored with `q` (vector grids as Vec3f).
fn nano_grids(file: &VdbFile, q: Quantise) -> Vec<NanoGrid<'_>> {
    file.grids
        .iter()
        .map(|g| NanoGrid {
            name: g.name.clone(),
            class: GridClass::from_openvdb(g.class),
            values: match &g.data {
                GridData::Float(s) => NanoValues::Float(s, q),
                GridData::Vec3(s) => NanoValues::Vec3(s),
            },
        })
        .collect()
}

fn load(source: &Source) -> Result<(VdbFile, String)> {
    match source {
        Source::Cloud(n) => Ok((
            VdbFile {
                grids: vec![VdbGrid::float("density", cloud_grid(*n))],
                metadata: VdbFile::standard_metadata(1),
            },
            format!("synthetic cloud of {n} voxels"),
        )),
        Source::File(path) => {
            let read = vdb::read_file(path)?;
            let grids = read
                .grids
                .into_iter()
                .filter(|g| g.instance_parent.is_none())
                .map(|g| VdbGrid {
                    class: match g.meta("class") {
                        Some(vdb::MetaValue::String(c)) if c == vdb::CLASS_FOG_VOLUME => {
                            vdb::CLASS_FOG_VOLUME
                        }
                        _ => vdb::CLASS_UNKNOWN,
                    },
                    name: g.name,
                    aliases: Vec::new(),
                    data: g.data,
                    metadata: Vec::new(),
                })
                .collect();
            Ok((
                VdbFile {
                    grids,
                    metadata: read.metadata,
                },
                path.display().to_string(),
            ))
        }
    }
}

/// Runs `nanovdb_convert -f -c full FLAGS IN OUT` once; its wall time in ms.
fn convert(input: &Path, output: &Path, flags: &[&str]) -> std::result::Result<f64, String> {
    let t = Instant::now();
    let o = std::process::Command::new("nanovdb_convert")
        .args(["-f", "-c", "full"])
        .args(flags)
        .arg(input)
        .arg(output)
        .output()
        .map_err(|e| format!("nanovdb_convert: {e} (tools/setup.sh installs libnanovdb-tools)"))?;
    let dt = ms(t);
    if !o.status.success() {
        return Err(String::from_utf8_lossy(&o.stderr).trim().to_string());
    }
    Ok(dt)
}

/// Times nimbus's NanoVDB writer (in memory, and to a file with fsync + rename) and
/// `nanovdb_convert` on the same grids, float; then the size of each precision, and whether
/// the converter's file of that precision is byte for byte nimbus's.
pub fn bench_nanovdb_write(
    source: &Source,
    reps: usize,
    tolerance: f64,
) -> Result<serde_json::Value> {
    let reps = reps.max(1);
    let (file, what) = load(source)?;
    let active: u64 = file.grids.iter().map(|g| g.active_voxel_count()).sum();
    let dir = std::env::temp_dir().join(format!("nimbus-bench-nanovdb-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let input = dir.join("input.vdb");
    vdb::write_file(
        &input,
        &file,
        &VdbOptions {
            compression: Compression::None,
            half: false,
        },
    )?;
    let ours = dir.join("nimbus.nvdb");
    let theirs = dir.join("convert.nvdb");

    // Side by side, alternating, so a load change on the machine hits both.
    let grids = nano_grids(&file, Quantise::Float);
    let (mut encode_ms, mut write_ms, mut convert_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut cached_ms = Vec::new();
    let mut convert_error = None;
    for _ in 0..reps {
        let t = Instant::now();
        let enc = nanovdb::encode(&grids)?;
        encode_ms.push(ms(t));
        drop(enc);
        // Like the converter: encoded and written into the page cache, no fsync.
        let t = Instant::now();
        let enc = nanovdb::encode(&grids)?;
        let f = std::fs::File::create(&ours).map_err(|e| Error::io(&ours, e))?;
        let mut w = std::io::BufWriter::with_capacity(1 << 20, f);
        enc.write_to(&mut w)
            .and_then(|_| std::io::Write::flush(&mut w))
            .map_err(|e| Error::io(&ours, e))?;
        drop(w);
        cached_ms.push(ms(t));
        drop(enc);
        // What a frame costs: atomic, with fsync and rename.
        let t = Instant::now();
        nanovdb::write_file(&ours, &grids)?;
        write_ms.push(ms(t));
        match convert(&input, &theirs, &[]) {
            Ok(dt) => convert_ms.push(dt),
            Err(e) => {
                convert_error = Some(e);
                break;
            }
        }
    }

    // Sizes per precision (the float grids quantised, vector grids Vec3f), and the converter's
    // file of the same precision compared byte for byte.
    let mut sizes = serde_json::Map::new();
    for (name, flags) in [
        ("float", vec![]),
        ("fp16", vec!["--fp16".to_string()]),
        ("fp8", vec!["--fp8".to_string()]),
        ("fp4", vec!["--fp4".to_string()]),
        ("fpn", vec![]),
    ] {
        // FpN: nimbus's tolerance is per grid (a fraction of its range); the converter takes
        // one absolute tolerance, so it is compared on single-grid files only.
        let tolerances: Vec<f32> = file
            .grids
            .iter()
            .map(|g| match &g.data {
                GridData::Float(s) => crate::pipeline::writer::fpn_tolerance(s, tolerance),
                GridData::Vec3(_) => 0.0,
            })
            .collect();
        let q = |i: usize| match name {
            "float" => Quantise::Float,
            "fp16" => Quantise::Fp16,
            "fp8" => Quantise::Fp8,
            "fp4" => Quantise::Fp4,
            _ => Quantise::FpN {
                tolerance: tolerances[i],
            },
        };
        let grids: Vec<NanoGrid> = nano_grids(&file, Quantise::Float)
            .into_iter()
            .enumerate()
            .map(|(i, mut g)| {
                if let NanoValues::Float(s, _) = g.values {
                    g.values = NanoValues::Float(s, q(i));
                }
                g
            })
            .collect();
        let bytes = nanovdb::encode(&grids)?.to_bytes();
        let mut entry = json!({ "bytes": bytes.len() });
        let flags: Vec<String> = if name == "fpn" {
            if file.grids.len() == 1 {
                vec!["-a".into(), format!("{:.8e}", tolerances[0])]
            } else {
                Vec::new()
            }
        } else {
            flags
        };
        if convert_error.is_none() && (name != "fpn" || !flags.is_empty()) {
            let f: Vec<&str> = flags.iter().map(String::as_str).collect();
            if convert(&input, &theirs, &f).is_ok() {
                let same = std::fs::read(&theirs).map(|t| t == bytes).unwrap_or(false);
                entry["same_bytes_as_nanovdb_convert"] = json!(same);
            }
        }
        sizes.insert(name.into(), entry);
    }
    let vdb_bytes = vdb::encode(&file, &VdbOptions::default())?.len;
    let _ = std::fs::remove_dir_all(&dir);

    let mut report = json!({
        "bench": "nanovdb_write",
        "source": what,
        "grids": file.grids.iter().map(|g| g.name.clone()).collect::<Vec<_>>(),
        "active_voxels": active,
        "threads": rayon::current_num_threads(),
        "reps": reps,
        "nimbus": {
            "encode_ms": summary(encode_ms.clone()),
            "write_no_fsync_ms": summary(cached_ms.clone()),
            "write_fsync_ms": summary(write_ms.clone()),
        },
        "sizes": sizes,
        "vdb_blosc_bytes": vdb_bytes,
        "fpn_tolerance": tolerance,
    });
    match convert_error {
        Some(e) => report["nanovdb_convert"] = json!({ "skipped": e }),
        None => {
            report["nanovdb_convert"] = json!({ "ms": summary(convert_ms.clone()) });
            let c = min(&convert_ms);
            let med = |v: &[f64]| {
                let mut v = v.to_vec();
                v.sort_by(|a, b| a.total_cmp(b));
                v[v.len() / 2]
            };
            report["speedup_vs_nanovdb_convert"] = json!({
                "encode_min": c / min(&encode_ms),
                "write_no_fsync_min": c / min(&cached_ms),
                "write_no_fsync_median": med(&convert_ms) / med(&cached_ms),
                "write_fsync_min": c / min(&write_ms),
                "write_fsync_median": med(&convert_ms) / med(&write_ms),
            });
        }
    }
    Ok(report)
}
