//! `nimbus bench detail RUN_DIR`: the figures of `export.detail` (docs/RENDERING.md "Detail at the
//! surface", docs/PERFORMANCE.md), measured on a run's particle caches (the run needs
//! `export.particles` and `export.detail.enabled` or `export.grids.rest`, so the caches hold the
//! rest positions). Per frame, at `--voxel` (default: spacing / 4), with the run's detail settings
//! (detail switched on if the run had it off):
//! - mass: sum of the detailed density over the undetailed one, and per 8^3 leaf (the
//!   particle-scale block: 2 spacings at spacing / 4) the density-weighted mean |ratio - 1|;
//! - energy below the particle spacing: the density grid's power spectrum (3-D FFT of the
//!   active bounding box, zero-padded to powers of two) summed over wavenumbers |k| > 1 / spacing,
//!   detailed over undetailed;
//! - frame-to-frame correlation of the detail component (detailed - undetailed density) in the
//!   rest frame: each active voxel of frame f+1 against the point of frame f with the same rest
//!   coordinate, frame f's detail evaluated exactly there from the particles (`PointSplat`,
//!   `exact_correlation`; also the older figure that interpolates frame f's grid, `RestMatch`,
//!   the modulation detailed / undetailed - 1 alone, and the cosine similarity of the undetailed
//!   density itself at the matched points, the cloud's own change that bounds the detail's
//!   correlation); and at the same material points:
//!   each particle present in frames f and f+1 (matched by id) and 26 points a quarter spacing
//!   around it, sampled at its position in each frame (trilinear). Pearson correlation, for the
//!   rest-frame noise and for the same noise evaluated in world space;
//! - time: `FrameWriter::write` of the frame with the run's grids at that voxel size and VDB only
//!   (no EXR, preview or cache): splat + detail, and the VDB write, against the simulation's own
//!   milliseconds per frame from the run's stats.jsonl.
use super::surface;
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::export::ExportSpace;
use crate::ground::rest::{RestCodec, RestFrame};
use crate::ground::SparseGrid;
use crate::ground::{levels, ParticleState};
use crate::pipeline::records::{Manifest, StatsLine, WriterTimes};
use crate::pipeline::run_dir::RunDir;
use crate::pipeline::writer::{FrameJob, FrameWriter};
use crate::splat::detail::{DetailNoise, EdgeSums, NoiseSpace};
use crate::splat::{splat_with_rest, RestInput, SplatFields, SplatParams};
use serde_json::json;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

struct Frame {
    state: ParticleState,
    rest: RestFrame,
}

/// What `nimbus bench detail` measures.
#[derive(Debug, Clone, PartialEq)]
pub struct DetailBench {
    /// Frames A-B (default: all the run has).
    pub frames: Option<(u32, u32)>,
    /// Voxel size (m); default: spacing / 4.
    pub voxel: Option<f64>,
    /// Only the mass and the surface figures.
    pub surface_only: bool,
    /// Density of the boundary the surface figures measure from (density grid units).
    pub boundary: f64,
}

pub fn bench_detail(
    run_dir: &Path,
    opts: &DetailBench,
    sets: &[String],
) -> Result<serde_json::Value> {
    let (frames, voxel) = (opts.frames, opts.voxel);
    crate::pipeline::reexport::check_sets(sets)?;
    let manifest = Manifest::load(&RunDir::new(run_dir))?;
    let text =
        serde_json::to_string(&manifest.config).map_err(|e| Error::Runtime(e.to_string()))?;
    let shot = crate::shot::load_str(&text, RunDir::MANIFEST, sets)?;
    let mut cfg: ShotConfig = shot.config().clone();
    if !cfg.export.particles || !cfg.export.tracks_rest() {
        return Err(Error::InvalidInput(format!(
            "{}: needs a run with export.particles and export.detail.enabled (or export.grids.rest): its caches hold the rest positions",
            run_dir.display()
        )));
    }
    let spacing = cfg.domain.spacing;
    let voxel = voxel.unwrap_or(spacing / 4.0);
    let space = ExportSpace::from_config(&cfg);
    cfg.export.voxel_size = voxel;
    cfg.export.detail.enabled = true;
    let codec = RestCodec::new(
        cfg.domain.size,
        [
            cfg.domain.periodic.contains(&crate::config::Axis::X),
            cfg.domain.periodic.contains(&crate::config::Axis::Z),
        ],
    );
    let clock = crate::sim::rest::rest_clock(&cfg);
    let (a, b) = frames.unwrap_or((
        manifest.frames.first().map_or(0, |f| f.frame),
        manifest.frames.last().map_or(0, |f| f.frame),
    ));
    let read = |f: u32| -> Result<Frame> {
        let rec = manifest
            .frame(f)
            .ok_or_else(|| Error::InvalidInput(format!("frame {f} is not in the manifest")))?;
        let ply = rec
            .files
            .iter()
            .find(|x| x.path.ends_with(".ply"))
            .ok_or_else(|| Error::InvalidInput(format!("frame {f}: no particle cache")))?;
        let (state, rest) = crate::io::ply::read_with_rest(
            &run_dir.join(&ply.path),
            &space,
            cfg.solver.rest_density as f32,
            Some(codec),
        )?;
        let rest =
            rest.ok_or_else(|| Error::InvalidInput(format!("frame {f}: no rest positions")))?;
        Ok(Frame { state, rest })
    };
    let mut base = SplatParams::from_config(&cfg)?;
    base.fields = SplatFields {
        density: true,
        temperature: false,
        vapor: false,
        velocity: false,
        rest: false,
    };
    let detail = base.detail.clone().expect("detail on");
    let density = |fr: &Frame, f: u32, space: Option<NoiseSpace>| -> Result<SparseGrid<f32>> {
        let mut p = base.clone();
        p.detail = space.map(|s| {
            let mut d = detail.clone();
            d.space = s;
            d
        });
        let input = RestInput {
            rest: &fr.rest,
            codec,
            weights: clock.weights(f),
            dual: clock.dual(),
        };
        let g = splat_with_rest(&fr.state, &p, Some(input))?;
        g.density
            .ok_or_else(|| Error::Runtime("no density grid".into()))
    };

    // The timed export: the run's grids at this voxel size, VDB only, into a scratch directory.
    let scratch = std::env::temp_dir().join(format!("nimbus-bench-detail-{}", std::process::id()));
    let mut wcfg = cfg.clone();
    wcfg.export.exr.enabled = false;
    wcfg.output.preview.enabled = false;
    wcfg.export.particles = false;
    let scratch_run = RunDir::new(&scratch);
    scratch_run.create_dirs(true)?;
    let writer = FrameWriter::new(&shot, &wcfg, &scratch_run)?;
    let mut plain_cfg = wcfg.clone();
    plain_cfg.export.detail.enabled = false;
    plain_cfg.export.grids.rest = String::new();
    let plain_writer = FrameWriter::new(&shot, &plain_cfg, &scratch_run)?;

    let sim_ms = sim_ms_per_frame(run_dir);
    let mut rows = Vec::new();
    let rest_grids = |fr: &Frame, f: u32| -> Result<[SparseGrid<[f32; 3]>; 2]> {
        let mut p = base.clone();
        p.fields.density = false;
        p.fields.rest = true;
        let input = RestInput {
            rest: &fr.rest,
            codec,
            weights: clock.weights(f),
            dual: true,
        };
        let g = splat_with_rest(&fr.state, &p, Some(input))?;
        match (g.rest, g.rest2) {
            (Some(a), Some(b)) => Ok([a, b]),
            _ => Err(Error::Runtime("no rest grids".into())),
        }
    };
    type Prev = (
        u32,
        Frame,
        SparseGrid<f32>,
        SparseGrid<f32>,
        SparseGrid<f32>,
    );
    let mut prev: Option<Prev> = None;
    let mut prev_rest: Option<[SparseGrid<[f32; 3]>; 2]> = None;
    type PrevPs = (PointSplat, [DetailNoise; 2], [f64; 2]);
    let mut prev_ps: Option<PrevPs> = None;
    for f in a..=b {
        let fr = read(f)?;
        let d0 = density(&fr, f, None)?;
        let d1 = density(&fr, f, Some(NoiseSpace::Rest))?;
        let dw = density(&fr, f, Some(NoiseSpace::World))?;
        let s0 = grid_sum(&d0);
        let mut row = json!({"frame": f, "active_voxels": d0.active_voxel_count(), "detailed_active_voxels": d1.active_voxel_count()});
        if s0 > 0.0 {
            row["mass_ratio"] = json!(grid_sum(&d1) / s0);
            row["block_mass_deviation"] = json!(block_deviation(&d0, &d1));
            let e0 = high_energy(&d0, spacing);
            let e1 = high_energy(&d1, spacing);
            let ew = high_energy(&dw, spacing);
            row["energy_below_spacing_ratio"] = json!(e1 / e0);
            row["energy_below_spacing_ratio_world"] = json!(ew / e0);
            if let Some(sf) =
                surface::surface_figures(&d0, &d1, opts.boundary, 2.0 * spacing, spacing, spacing)
            {
                row["inside_rms_change"] = json!(sf.inside_rms_change);
                row["inside_voxels"] = json!(sf.inside_voxels);
                row["shell_energy_ratio"] = json!(sf.shell_energy_ratio);
                row["shell_voxels"] = json!(sf.shell_voxels);
                row["thickness_undetailed_voxels"] = json!(sf.thickness_undetailed);
                row["thickness_detailed_voxels"] = json!(sf.thickness_detailed);
            }
        }
        if opts.surface_only {
            eprintln!("{row}");
            rows.push(row);
            continue;
        }
        let rg = rest_grids(&fr, f)?;
        if let (Some((_, pfr, ..)), Some(pr)) = (&prev, &prev_rest) {
            let resets = clock.resets(f);
            let mut d2 = Vec::new();
            for k in 0..2 {
                if !resets[k] {
                    d2.extend(rest_moves(pfr, &pr[k], &fr, &rg[k]));
                }
            }
            if !d2.is_empty() {
                d2.sort_by(f64::total_cmp);
                let rms = (d2.iter().sum::<f64>() / d2.len() as f64).sqrt();
                row["rest_move_rms_m"] = json!(rms);
                row["rest_move_median_m"] = json!(d2[d2.len() / 2].sqrt());
            }
        }
        if let (Some((pf, pfr, p0, p1, pw)), Some(pr)) = (&prev, &prev_rest) {
            if s0 > 0.0 && grid_sum(p0) > 0.0 {
                row["correlation_frames"] = json!([pf, f]);
                // the field that carries on (not reset on f), the younger one if both do
                let resets = clock.resets(f);
                let age = clock.ages(f);
                let k = match resets {
                    [false, true] => Some(0),
                    [true, false] => Some(1),
                    [false, false] => Some(if age[0] <= age[1] { 0 } else { 1 }),
                    _ => None,
                };
                if let (Some(k), Some((ps_a, noises, norm))) = (k, &prev_ps) {
                    let ps_b = PointSplat::new(&fr, &base, codec);
                    let [cr, cw, mr, mw, own] = exact_correlation(
                        ps_a, &noises[0], &noises[1], *norm, k, &ps_b, &d0, &d1, &dw,
                    );
                    row["detail_correlation_rest_exact"] = json!(cr);
                    row["detail_correlation_world_exact"] = json!(cw);
                    row["modulation_correlation_rest_exact"] = json!(mr);
                    row["modulation_correlation_world_exact"] = json!(mw);
                    row["undetailed_cosine_rest_exact"] = json!(own);
                }
                if let Some(k) = k {
                    let m = RestMatch {
                        rest_a: &pr[k],
                        rest_b: &rg[k],
                    };
                    row["detail_correlation_rest"] = json!(m.correlation(p0, p1, &d0, &d1));
                    row["detail_correlation_world"] = json!(m.correlation(p0, pw, &d0, &dw));
                }
                row["particle_correlation_rest"] =
                    json!(correlation(pfr, p0, p1, &fr, &d0, &d1, spacing));
                row["particle_correlation_world"] =
                    json!(correlation(pfr, p0, pw, &fr, &d0, &dw, spacing));
            }
        }
        prev_rest = Some(rg);
        {
            let ps = PointSplat::new(&fr, &base, codec);
            let mk = |sp: NoiseSpace| {
                let mut d = detail.clone();
                d.space = sp;
                DetailNoise::new(
                    &d,
                    base.domain_size,
                    voxel,
                    clock.weights(f),
                    base.cloud_scale,
                )
            };
            let noises = [mk(NoiseSpace::Rest), mk(NoiseSpace::World)];
            let norm = [
                normalisation(&ps, &noises[0], &d0),
                normalisation(&ps, &noises[1], &d0),
            ];
            prev_ps = Some((ps, noises, norm));
        }
        // timings: best of two
        let timed = |w: &FrameWriter| -> Result<(f64, f64)> {
            let mut best = (f64::INFINITY, f64::INFINITY);
            for _ in 0..2 {
                let out = w.write(FrameJob {
                    frame: f,
                    state: Arc::new(fr.state.clone()),
                    skip_write: false,
                    started: Instant::now(),
                    rest: Some(Arc::new(fr.rest.clone())),
                })?;
                let s = out.phase_ms.splat.unwrap_or(0.0);
                let v = out.phase_ms.write_vdb.unwrap_or(0.0);
                if s + v < best.0 + best.1 {
                    best = (s, v);
                }
            }
            Ok(best)
        };
        let (ds, dv) = timed(&writer)?;
        let (ps, pv) = timed(&plain_writer)?;
        row["detail_splat_ms"] = json!(ds);
        row["detail_vdb_ms"] = json!(dv);
        row["detail_total_ms"] = json!(ds + dv);
        row["plain_splat_ms"] = json!(ps);
        row["plain_vdb_ms"] = json!(pv);
        eprintln!("{row}");
        rows.push(row);
        prev = Some((f, fr, d0, d1, dw));
    }
    let _ = std::fs::remove_dir_all(&scratch);
    let mean = |key: &str| {
        let v: Vec<f64> = rows.iter().filter_map(|r| r[key].as_f64()).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    let min = |key: &str| rows.iter().filter_map(|r| r[key].as_f64()).reduce(f64::min);
    let max = |key: &str| rows.iter().filter_map(|r| r[key].as_f64()).reduce(f64::max);
    Ok(json!({
        "run": run_dir.display().to_string(),
        "voxel_size": voxel,
        "spacing": spacing,
        "detail": serde_json::to_value(&cfg.export.detail).unwrap_or_default(),
        "boundary": opts.boundary,
        "frames": [a, b],
        "summary": {
            "mass_ratio_min": min("mass_ratio"),
            "mass_ratio_max": max("mass_ratio"),
            "block_mass_deviation_mean": mean("block_mass_deviation"),
            "inside_rms_change_max": max("inside_rms_change"),
            "shell_energy_ratio_min": min("shell_energy_ratio"),
            "energy_below_spacing_ratio_min": min("energy_below_spacing_ratio"),
            "energy_below_spacing_ratio_mean": mean("energy_below_spacing_ratio"),
            "detail_correlation_rest_min": min("detail_correlation_rest"),
            "detail_correlation_rest_mean": mean("detail_correlation_rest"),
            "detail_correlation_world_mean": mean("detail_correlation_world"),
            "detail_correlation_world_max": max("detail_correlation_world"),
            "detail_correlation_rest_exact_min": min("detail_correlation_rest_exact"),
            "detail_correlation_rest_exact_max": max("detail_correlation_rest_exact"),
            "detail_correlation_rest_exact_mean": mean("detail_correlation_rest_exact"),
            "detail_correlation_world_exact_mean": mean("detail_correlation_world_exact"),
            "detail_correlation_world_exact_min": min("detail_correlation_world_exact"),
            "detail_correlation_world_exact_max": max("detail_correlation_world_exact"),
            "undetailed_cosine_rest_exact_min": min("undetailed_cosine_rest_exact"),
            "undetailed_cosine_rest_exact_mean": mean("undetailed_cosine_rest_exact"),
            "energy_below_spacing_ratio_world_min": min("energy_below_spacing_ratio_world"),
            "particle_correlation_rest_mean": mean("particle_correlation_rest"),
            "particle_correlation_world_mean": mean("particle_correlation_world"),
            "rest_move_median_m_mean": mean("rest_move_median_m"),
            "detail_total_ms_mean": mean("detail_total_ms"),
            "detail_total_ms_max": max("detail_total_ms"),
            "plain_total_ms_mean": mean("plain_splat_ms").zip(mean("plain_vdb_ms")).map(|(a, b)| a + b),
            "sim_ms_per_frame_mean": sim_ms,
        },
        "rows": rows,
    }))
}

/// Mean simulation milliseconds per frame from the run's stats.jsonl (the GPU phases: every
/// phase but the writer's).
fn sim_ms_per_frame(run_dir: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(RunDir::new(run_dir).stats()).ok()?;
    let mut v = Vec::new();
    for line in text.lines() {
        let s: StatsLine = serde_json::from_str(line).ok()?;
        let ms: f64 = s
            .phase_ms
            .iter()
            .filter(|(k, _)| !WriterTimes::KEYS.contains(&k.as_str()))
            .map(|(_, x)| x)
            .sum();
        v.push(ms);
    }
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn grid_sum(g: &SparseGrid<f32>) -> f64 {
    let mut s = 0.0;
    for l in &g.leaves {
        for n in 0..512 {
            if l.is_active(n) {
                s += l.values[n] as f64;
            }
        }
    }
    s
}

fn leaf_sums(g: &SparseGrid<f32>) -> std::collections::BTreeMap<[i32; 3], f64> {
    g.leaves
        .iter()
        .map(|l| {
            let s: f64 = (0..512)
                .filter(|&n| l.is_active(n))
                .map(|n| l.values[n] as f64)
                .sum();
            (l.origin, s)
        })
        .collect()
}

/// Density-weighted mean of |detailed / undetailed - 1| over the 8^3 leaves.
fn block_deviation(d0: &SparseGrid<f32>, d1: &SparseGrid<f32>) -> f64 {
    let a = leaf_sums(d0);
    let b = leaf_sums(d1);
    let (mut num, mut den) = (0.0, 0.0);
    for (k, s0) in &a {
        if *s0 > 0.0 {
            let s1 = b.get(k).copied().unwrap_or(0.0);
            num += (s1 - s0).abs();
            den += s0;
        }
    }
    if den > 0.0 {
        num / den
    } else {
        0.0
    }
}

/// Spectral energy at wavelengths below `spacing` (|k| > 1 / spacing).
fn high_energy(g: &SparseGrid<f32>, spacing: f64) -> f64 {
    let Some((lo, hi)) = g.active_bbox() else {
        return 0.0;
    };
    let dims = [0, 1, 2].map(|a| ((hi[a] - lo[a] + 1) as usize).next_power_of_two());
    let [nx, ny, nz] = dims;
    let mut re = vec![0.0f64; nx * ny * nz];
    let mut im = vec![0.0f64; nx * ny * nz];
    let idx = |x: usize, y: usize, z: usize| (x * ny + y) * nz + z;
    for l in &g.leaves {
        for n in 0..512 {
            if l.is_active(n) {
                let p = [
                    l.origin[0] + (n >> 6) as i32 - lo[0],
                    l.origin[1] + ((n >> 3) & 7) as i32 - lo[1],
                    l.origin[2] + (n & 7) as i32 - lo[2],
                ];
                re[idx(p[0] as usize, p[1] as usize, p[2] as usize)] = l.values[n] as f64;
            }
        }
    }
    surface::fft3(&mut re, &mut im, dims, false);
    let v = g.transform.voxel_size;
    let kmin = 1.0 / spacing;
    let freq = |k: usize, n: usize| {
        let k = if k > n / 2 {
            k as f64 - n as f64
        } else {
            k as f64
        };
        k / (n as f64 * v)
    };
    let mut e = 0.0;
    for x in 0..nx {
        for y in 0..ny {
            for z in 0..nz {
                let f = [freq(x, nx), freq(y, ny), freq(z, nz)];
                if (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() > kmin {
                    let i = idx(x, y, z);
                    e += re[i] * re[i] + im[i] * im[i];
                }
            }
        }
    }
    e
}

/// Trilinear value at a world position (background 0 outside the active voxels).
fn sample(g: &SparseGrid<f32>, p: [f64; 3]) -> f64 {
    let mut s = 0.0;
    for (i, w) in surface::trilinear_corners(g.transform.world_to_index(p)) {
        s += w * g.get(i.map(|v| v as i32)) as f64;
    }
    s
}

/// Correlation of the detail component (detailed - undetailed) between two frames at the same
/// material points (see the module docs).
fn correlation(
    fa: &Frame,
    a0: &SparseGrid<f32>,
    a1: &SparseGrid<f32>,
    fb: &Frame,
    b0: &SparseGrid<f32>,
    b1: &SparseGrid<f32>,
    spacing: f64,
) -> f64 {
    let mut where_b = std::collections::HashMap::new();
    for (j, info) in fb.state.info.iter().enumerate() {
        where_b.insert(info[0], j);
    }
    let q = spacing / 4.0;
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for (i, info) in fa.state.info.iter().enumerate() {
        let Some(&j) = where_b.get(&info[0]) else {
            continue;
        };
        let pa = fa.state.pos[i];
        let pb = fb.state.pos[j];
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let o = [dx as f64 * q, dy as f64 * q, dz as f64 * q];
                    let x = [
                        pa[0] as f64 + o[0],
                        pa[1] as f64 + o[1],
                        pa[2] as f64 + o[2],
                    ];
                    let y = [
                        pb[0] as f64 + o[0],
                        pb[1] as f64 + o[1],
                        pb[2] as f64 + o[2],
                    ];
                    let (u0, v0) = (sample(a0, x), sample(b0, y));
                    if u0 <= 0.0 && v0 <= 0.0 {
                        continue;
                    }
                    xs.push(sample(a1, x) - u0);
                    ys.push(sample(b1, y) - v0);
                }
            }
        }
    }
    pearson(&xs, &ys)
}

/// Points of two frames matched by their rest coordinate (one rest field, not reset between
/// them): for each active voxel y of the undetailed density of the second frame, the point x of
/// the first with rest_a(x) = rest_b(y), by three Newton steps x -= rest_a(x) - rest_b(y) from
/// x = y (d rest / dx is about the identity).
struct RestMatch<'a> {
    rest_a: &'a SparseGrid<[f32; 3]>,
    rest_b: &'a SparseGrid<[f32; 3]>,
}

impl RestMatch<'_> {
    fn correlation(
        &self,
        a0: &SparseGrid<f32>,
        a1: &SparseGrid<f32>,
        b0: &SparseGrid<f32>,
        b1: &SparseGrid<f32>,
    ) -> f64 {
        let t = b0.transform;
        let (mut xs, mut ys) = (Vec::new(), Vec::new());
        for ijk in b0.active_voxels() {
            let y = t.index_to_world(ijk.map(|v| v as f64));
            let target = self.rest_b.get(ijk).map(|v| v as f64);
            let mut x = y;
            let mut ok = true;
            for _ in 0..3 {
                let Some(r) = sample3(self.rest_a, x) else {
                    ok = false;
                    break;
                };
                for k in 0..3 {
                    x[k] -= r[k] - target[k];
                }
            }
            if !ok {
                continue;
            }
            let u0 = sample(a0, x);
            xs.push(sample(a1, x) - u0);
            ys.push(b1.get(ijk) as f64 - b0.get(ijk) as f64);
        }
        pearson(&xs, &ys)
    }
}

/// The splat evaluated at any point, not only at voxel centres: the undetailed density
/// sum_j V_j W(x - x_j) c_j and the Shepard displacement of both rest fields (the particles'
/// displacements smoothed over `rest_smoothing` x h first, `splat::rest_smooth`), with the
/// kernels and minimum image of `splat` (periodic x and z). The rest-frame correlation evaluates frame
/// f's detail exactly at the matched point with it instead of interpolating the 12.5 m grid
/// between voxels (trilinear interpolation of a field with 40 m cells attenuates it by up to
/// half between voxels, and only one side of each pair was interpolated).
struct PointSplat {
    parts: Vec<PointSource>,
    cell: f64,
    bins: std::collections::HashMap<[i64; 3], Vec<usize>>,
    size: [f64; 3],
    periodic: [bool; 3],
}

struct PointSource {
    x: [f64; 3],
    h: f64,
    h2: f64,
    c: f64,
    cloud: f64,
    share: f64,
    disp: [[f64; 3]; 2],
}

#[allow(clippy::needless_range_loop)] // per-axis periodic wrap over three arrays
impl PointSplat {
    fn new(fr: &Frame, p: &SplatParams, codec: RestCodec) -> Self {
        let size = p.domain_size;
        let periodic = [p.periodic[0], false, p.periodic[1]];
        let cell = p.h0;
        let input = crate::splat::RestInput {
            rest: &fr.rest,
            codec,
            weights: [0.5; 2],
            dual: true,
        };
        let all = vec![true; fr.state.len()];
        let smoothed =
            crate::splat::rest_smooth::smoothed_displacements(&fr.state, &input, p, &all);
        let mut parts = Vec::new();
        let mut bins: std::collections::HashMap<[i64; 3], Vec<usize>> = Default::default();
        let rho_min = crate::splat::MIN_DENSITY_RATIO * p.rest_density;
        for j in 0..fr.state.len() {
            let pw = fr.state.pos[j];
            let mut x = [pw[0] as f64, pw[1] as f64, pw[2] as f64];
            if !x.iter().all(|v| v.is_finite()) {
                continue;
            }
            for a in 0..3 {
                if periodic[a] {
                    x[a] = x[a].rem_euclid(size[a]);
                }
            }
            let level = fr.state.info[j][1] as f64;
            if level > 60.0 {
                continue;
            }
            let h = levels::radius(p.h0, fr.state.info[j][1]);
            let m = levels::mass(p.m0, fr.state.info[j][1]);
            let rho = (fr.state.density[j] as f64).max(rho_min);
            let rho = if rho.is_finite() { rho } else { rho_min };
            let c = m / rho * 315.0 / (64.0 * std::f64::consts::PI * h.powi(9));
            let Some(disp) = smoothed[j] else {
                continue;
            };
            bins.entry(x.map(|v| (v / cell).floor() as i64))
                .or_default()
                .push(parts.len());
            parts.push(PointSource {
                x,
                h,
                h2: h * h,
                c,
                cloud: fr.state.thermo[j][2] as f64 * p.cloud_scale,
                share: crate::splat::detail::cloud_share(
                    fr.state.thermo[j][2] as f64,
                    crate::splat::detail::EDGE_WATER,
                ),
                disp,
            });
        }
        Self {
            parts,
            cell,
            bins,
            size,
            periodic,
        }
    }

    /// (undetailed density, rest coordinates of field A and B) at `x`; `None` outside every
    /// support.
    fn eval(&self, x: [f64; 3]) -> Option<(f64, [[f64; 3]; 2])> {
        self.eval_sums(x).map(|(s, r)| (s.dens, r))
    }

    /// The detail's kernel sums at `x` and the rest coordinates of field A and B.
    fn eval_sums(&self, x: [f64; 3]) -> Option<(EdgeSums, [[f64; 3]; 2])> {
        let mut xx = x;
        for a in 0..3 {
            if self.periodic[a] {
                xx[a] = xx[a].rem_euclid(self.size[a]);
            }
        }
        let b = xx.map(|v| (v / self.cell).floor() as i64);
        let n = [0, 1, 2].map(|a| (self.size[a] / self.cell).ceil() as i64);
        let mut sums = EdgeSums::default();
        let mut d = [0.0f64; 6];
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let mut k = [b[0] + dx, b[1] + dy, b[2] + dz];
                    for a in 0..3 {
                        if self.periodic[a] {
                            k[a] = k[a].rem_euclid(n[a]);
                        }
                    }
                    let Some(list) = self.bins.get(&k) else {
                        continue;
                    };
                    for &j in list {
                        let s = &self.parts[j];
                        let mut r2 = 0.0;
                        let mut e = [0.0; 3];
                        for a in 0..3 {
                            e[a] = xx[a] - s.x[a];
                            if self.periodic[a] {
                                e[a] -= (e[a] / self.size[a]).round() * self.size[a];
                            }
                            r2 += e[a] * e[a];
                        }
                        if r2 < s.h2 {
                            let dd = s.h2 - r2;
                            let w = s.c * dd * dd * dd;
                            sums.add(w, -6.0 * s.c * dd * dd, e, s.cloud, s.share, s.h);
                            for a in 0..3 {
                                d[a] += w * s.disp[0][a];
                                d[3 + a] += w * s.disp[1][a];
                            }
                        }
                    }
                }
            }
        }
        (sums.cov > 0.0).then(|| {
            let r = |k: usize| [0, 1, 2].map(|a| x[a] - d[k + a] / sums.cov);
            (sums, [r(0), r(3)])
        })
    }
}

/// The rest-frame correlation with frame f's detail evaluated exactly at the matched points
/// (`PointSplat`): for each active voxel y of frame f+1's undetailed density, x in frame f with
/// rest_k,f(x) = rest_k,f+1(y) (Newton on the exact rest map from x = y), then frame f's detail
/// component d0(x) (g_f F_f(x) - 1), F the noise factor and g_f the frame's normalisation,
/// against the voxel's own detailed - undetailed value. Returns the rest-frame and world-noise
/// correlations, then the same for the modulation alone (detailed / undetailed - 1), then the
/// cosine similarity of the undetailed density itself at the same matched points: the cloud's
/// own change, which bounds the detail's correlation (for a noise n matched exactly and
/// independent of d0, corr(n d0_f, n d0_f+1) is that cosine).
#[allow(clippy::too_many_arguments)]
fn exact_correlation(
    ps: &PointSplat,
    noise_rest: &DetailNoise,
    noise_world: &DetailNoise,
    norm: [f64; 2],
    k: usize,
    ps_b: &PointSplat,
    b0: &SparseGrid<f32>,
    b1: &SparseGrid<f32>,
    bw: &SparseGrid<f32>,
) -> [f64; 5] {
    let t = b0.transform;
    let (mut xs, mut ys, mut xw, mut yw) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut own_xy, mut own_xx, mut own_yy) = (0.0, 0.0, 0.0);
    let (mut ms, mut my, mut mw, mut mwy) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for ijk in b0.active_voxels() {
        let y = t.index_to_world(ijk.map(|v| v as f64));
        let Some((_, rb)) = ps_b.eval(y) else {
            continue;
        };
        let target = rb[k];
        let mut x = y;
        let mut last = None;
        for _ in 0..4 {
            let Some(e) = ps.eval(x) else {
                last = None;
                break;
            };
            for a in 0..3 {
                x[a] -= e.1[k][a] - target[a];
            }
            last = Some(e);
        }
        if last.is_none() {
            continue;
        }
        let Some((sums, r)) = ps.eval_sums(x) else {
            continue;
        };
        let d0 = sums.dens;
        let detailed = |noise: &DetailNoise, k: f64| {
            noise
                .edge(&sums, x, r)
                .map_or(0.0, |(v, m)| v * (1.0 + k * m).max(0.0))
        };
        let (dr, dw) = (
            detailed(noise_rest, norm[0]),
            detailed(noise_world, norm[1]),
        );
        let v0 = b0.get(ijk) as f64;
        own_xy += d0 * v0;
        own_xx += d0 * d0;
        own_yy += v0 * v0;
        xs.push(dr - d0);
        ys.push(b1.get(ijk) as f64 - v0);
        xw.push(dw - d0);
        yw.push(bw.get(ijk) as f64 - v0);
        if d0 > 0.0 && v0 > 0.0 {
            ms.push(dr / d0 - 1.0);
            my.push(b1.get(ijk) as f64 / v0 - 1.0);
            mw.push(dw / d0 - 1.0);
            mwy.push(bw.get(ijk) as f64 / v0 - 1.0);
        }
    }
    [
        pearson(&xs, &ys),
        pearson(&xw, &yw),
        pearson(&ms, &my),
        pearson(&mw, &mwy),
        own_xy / (own_xx * own_yy).sqrt(),
    ]
}

/// The frame's mass factor k (`splat::edge_factor`), recomputed at the voxels of the
/// undetailed grid (the sub-threshold voxels left out: within a fraction of a percent of the
/// splat's own factor).
fn normalisation(ps: &PointSplat, noise: &DetailNoise, d0: &SparseGrid<f32>) -> f64 {
    let t = d0.transform;
    let (mut s0, mut s1, mut sm) = (0.0, 0.0, 0.0);
    for ijk in d0.active_voxels() {
        let x = t.index_to_world(ijk.map(|v| v as f64));
        if let Some((sums, r)) = ps.eval_sums(x) {
            s0 += sums.dens;
            if let Some((v, m)) = noise.edge(&sums, x, r) {
                s1 += v;
                sm += v * m;
            }
        }
    }
    crate::splat::edge_factor(s0, s1, sm)
}

/// Trilinear value of a vec3 grid; `None` where a corner is inactive.
fn sample3(g: &SparseGrid<[f32; 3]>, p: [f64; 3]) -> Option<[f64; 3]> {
    let mut s = [0.0; 3];
    for (i, w) in surface::trilinear_corners(g.transform.world_to_index(p)) {
        let i = i.map(|v| v as i32);
        let o = i.map(|v| v & !7);
        let leaf = g.leaves.binary_search_by(|l| l.origin.cmp(&o)).ok()?;
        let n = crate::ground::Leaf::<[f32; 3]>::offset(i[0], i[1], i[2]);
        if !g.leaves[leaf].is_active(n) {
            return None;
        }
        let v = g.leaves[leaf].values[n];
        for a in 0..3 {
            s[a] += w * v[a] as f64;
        }
    }
    Some(s)
}

/// Squared change of a rest field's interpolated coordinate at each cloudy particle (matched by
/// id) from one frame to the next: zero if the rest coordinate moved exactly with the particle.
fn rest_moves(
    fa: &Frame,
    ra: &SparseGrid<[f32; 3]>,
    fb: &Frame,
    rb: &SparseGrid<[f32; 3]>,
) -> Vec<f64> {
    let mut where_b = std::collections::HashMap::new();
    for (j, info) in fb.state.info.iter().enumerate() {
        where_b.insert(info[0], j);
    }
    let sample3 = |g: &SparseGrid<[f32; 3]>, p: [f32; 4]| {
        let x = g
            .transform
            .world_to_index([p[0] as f64, p[1] as f64, p[2] as f64]);
        let b = x.map(|v| v.floor());
        let t = [0, 1, 2].map(|a| x[a] - b[a]);
        let mut s = [0.0; 3];
        for c in 0..8 {
            let o = [c >> 2 & 1, c >> 1 & 1, c & 1];
            let w: f64 = (0..3)
                .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
                .product();
            let v = g.get([0, 1, 2].map(|a| b[a] as i32 + o[a]));
            for a in 0..3 {
                s[a] += w * v[a] as f64;
            }
        }
        s
    };
    let mut out = Vec::new();
    for (i, info) in fa.state.info.iter().enumerate() {
        if fa.state.thermo[i][2] <= 0.0 {
            continue;
        }
        let Some(&j) = where_b.get(&info[0]) else {
            continue;
        };
        let a = sample3(ra, fa.state.pos[i]);
        let b = sample3(rb, fb.state.pos[j]);
        out.push((0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum());
    }
    out
}

fn pearson(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    if n < 2.0 {
        return f64::NAN;
    }
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    sxy / (sxx * syy).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulation's time of a frame is its phases but every one of the writer's.
    #[test]
    fn sim_time_leaves_every_writer_phase_out() {
        let dir = tempfile::tempdir().unwrap();
        let line = |f: u32, pbf: f64| {
            format!(
                "{{\"frame\":{f},\"sim_time\":1.0,\"particles\":1,\"phase_ms\":{{\"pbf\":{pbf},\
                 \"grid\":1.0,\"splat\":5.0,\"write_vdb\":6.0,\"write_nanovdb\":7.0}},\
                 \"diagnostics\":{{}}}}\n"
            )
        };
        let text = line(1, 2.0) + &line(2, 4.0);
        std::fs::write(RunDir::new(dir.path()).stats(), text).unwrap();
        assert_eq!(sim_ms_per_frame(dir.path()), Some(4.0));
    }

    #[test]
    fn fft_of_a_cosine_has_its_two_peaks() {
        let n = 16;
        let mut re: Vec<f64> = (0..n)
            .map(|k| (2.0 * std::f64::consts::PI * 3.0 * k as f64 / n as f64).cos())
            .collect();
        let mut im = vec![0.0; n];
        surface::fft(&mut re, &mut im);
        for k in 0..n {
            let p = (re[k] * re[k] + im[k] * im[k]).sqrt();
            let want = if k == 3 || k == 13 { 8.0 } else { 0.0 };
            assert!((p - want).abs() < 1e-9, "{k}: {p}");
        }
        assert!((pearson(&[1.0, 2.0, 3.0], &[2.0, 4.0, 6.1]) - 1.0).abs() < 1e-3);
    }
}
