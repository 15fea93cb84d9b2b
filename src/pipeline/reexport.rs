//! `nimbus export RUN_DIR [--frames A-B] [--set export.key=value]... [--name NAME]`: re-makes the
//! VDB, EXR and preview files of a run from its particle caches (`export.particles`), without
//! simulating; frames in parallel (rayon), the unit of work a farm spreads over nodes.
//!
//! - With the run's own export settings it re-makes, in the run directory, the files of every
//!   frame whose files are missing or differ from the manifest, and checks that the new files
//!   have exactly the recorded size and SHA-256 (the splat is deterministic and the caches hold
//!   the simulation's own f32 values): the manifest is not rewritten.
//! - With other settings it writes `exports/<name>/` under the run (vdb/, exr/, preview/, nvdb/,
//!   the USD layer and its own manifest.json, which lists the frames exported so far; the layer
//!   holds the same frames); `<name>` defaults to a hash of
//!   the export settings, so farm jobs with the same `--set`s share one directory. Its manifest
//!   is updated under an exclusive lock of `exports/<name>/.lock`, held only for that update.
//!
//! With the run's own settings it writes into the run directory, so it holds the run's lock
//! shared (`RunLock::acquire_shared`): such exports run together, but not beside a `run`,
//! `resume` or `preview` of the same directory. Into `exports/<name>/` it writes nothing in the
//! run directory and reads only frames the manifest records (rewritten whole and atomically
//! after each frame), each cache checked against its recorded size and SHA-256 before use, so
//! it takes no run lock: a farm exports the first frames of a shot while the simulation (which
//! holds the lock exclusively) goes on, and a simulation requeued meanwhile is never refused
//! "in use" by an export.
use super::lock::RunLock;
use super::records::{file_record, FileRecord, FrameRecord, Manifest};
use super::run_dir::RunDir;
use super::writer::{FrameJob, FrameWriter};
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::export::ExportSpace;
use crate::shot::Shot;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

pub struct ExportRequest {
    /// Inclusive frame range; `None`: every frame of the run with a cache.
    pub frames: Option<(u32, u32)>,
    /// `export.*` overrides.
    pub sets: Vec<String>,
    /// Name of the export directory for other settings.
    pub name: Option<String>,
}

#[derive(Debug)]
pub struct ExportSummary {
    /// Where the files went (the run directory, or `exports/<name>`).
    pub dir: PathBuf,
    /// Frames re-made, and frames left as they were (own settings, files matching).
    pub written: Vec<u32>,
    pub unchanged: Vec<u32>,
}

/// Parses `A-B` (or a single frame `A`).
pub fn parse_frames(s: &str) -> Result<(u32, u32)> {
    let bad = || Error::InvalidInput(format!("--frames {s:?}: expected A-B, e.g. 10-20"));
    let (a, b) = s.split_once('-').unwrap_or((s, s));
    let a: u32 = a.trim().parse().map_err(|_| bad())?;
    let b: u32 = b.trim().parse().map_err(|_| bad())?;
    if a > b {
        return Err(bad());
    }
    Ok((a, b))
}

/// The shot of the run's resolved config from its manifest, with `sets` applied.
fn shot_of(manifest: &Manifest, run_dir: &Path, sets: &[String]) -> Result<Shot> {
    let text = serde_json::to_string_pretty(&manifest.config)
        .map_err(|e| Error::Runtime(e.to_string()))?;
    let origin = RunDir::new(run_dir).manifest();
    crate::shot::load_str(&text, &origin.to_string_lossy(), sets)
}

/// `nimbus export` changes `export.*` keys only, and not `export.particles`.
pub fn check_sets(sets: &[String]) -> Result<()> {
    for s in sets {
        let key = s.split_once('=').map_or(s.as_str(), |(k, _)| k).trim();
        if !key.starts_with("export.") || key == "export.particles" {
            return Err(Error::InvalidInput(format!(
                "--set {key}: nimbus export changes export.* keys only, and not export.particles: it re-splats particles already simulated"
            )));
        }
        if key == "export.detail.rest_period" {
            return Err(Error::InvalidInput(format!(
                "--set {key}: the rest positions in the particle caches were reset on the run's period; nimbus export cannot change it"
            )));
        }
    }
    Ok(())
}

pub fn export(run_dir: &Path, req: &ExportRequest) -> Result<ExportSummary> {
    check_sets(&req.sets)?;
    let run = RunDir::new(run_dir);
    let manifest = Manifest::load(&run)?;
    let run_cfg = shot_of(&manifest, run_dir, &[])?.into_config();
    let own = shot_of(&manifest, run_dir, &req.sets)?.config().export == run_cfg.export;
    // Own settings write into the run directory: held shared, and the manifest read again
    // under the lock. Another export directory needs no run lock (see the module's note).
    let (_lock, manifest) = if own {
        let lock = RunLock::acquire_shared(run_dir)?;
        (Some(lock), Manifest::load(&run)?)
    } else {
        (None, manifest)
    };
    let run_cfg = shot_of(&manifest, run_dir, &[])?.into_config();
    if !run_cfg.export.particles {
        return Err(Error::InvalidInput(format!(
            "{}: the run wrote no particle caches (export.particles: false), so there is nothing to export from",
            run_dir.display()
        )));
    }
    let shot = shot_of(&manifest, run_dir, &req.sets)?;
    let cfg = shot.config().clone();
    let frames: Vec<&FrameRecord> = manifest
        .frames
        .iter()
        .filter(|f| req.frames.is_none_or(|(a, b)| f.frame >= a && f.frame <= b))
        .collect();
    if let Some((a, b)) = req.frames {
        let missing: Vec<u32> = (a..=b).filter(|f| manifest.frame(*f).is_none()).collect();
        if !missing.is_empty() {
            return Err(Error::InvalidInput(format!(
                "{}: frames {} are not in the run's manifest (frames {}..={} recorded)",
                run_dir.display(),
                super::naming::frame_ranges(&missing),
                manifest.frames.first().map_or(0, |f| f.frame),
                manifest.frames.last().map_or(0, |f| f.frame)
            )));
        }
    }
    if frames.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: no frame to export",
            run_dir.display()
        )));
    }
    if cfg.export.tracks_rest() && !run_cfg.export.tracks_rest() {
        return Err(Error::InvalidInput(format!(
            "{}: export.detail and export.grids.rest need rest positions, and the run's particle caches hold none (run with export.detail.enabled or export.grids.rest set)",
            run_dir.display()
        )));
    }
    let run_space = ExportSpace::from_config(&run_cfg);
    let codec = cfg.export.tracks_rest().then(|| {
        crate::ground::rest::RestCodec::new(
            run_cfg.domain.size,
            [
                run_cfg.domain.periodic.contains(&crate::config::Axis::X),
                run_cfg.domain.periodic.contains(&crate::config::Axis::Z),
            ],
        )
    });
    let dest = if own {
        run.clone()
    } else {
        run.export_dir(&dir_name(&cfg, req.name.as_deref())?)
    };
    // The writer never writes caches again: it splats the ones it reads.
    let mut wcfg = cfg.clone();
    wcfg.export.particles = false;
    let writer = FrameWriter::new(&shot, &wcfg, &dest)?;
    dest.create_dirs(false)?;
    let out_manifest = if own {
        None
    } else {
        let mut m = writer.new_manifest(&wcfg, &manifest.adapter, &manifest.sim_hash)?;
        // not a run: nothing to resume
        m.resume_command = String::new();
        if let Ok(there) = Manifest::load(&dest) {
            if there.config != m.config {
                return Err(Error::InvalidInput(format!(
                    "{}: holds an export with other settings; choose another --name",
                    dest.root().display()
                )));
            }
        }
        Some(Mutex::new(m))
    };

    let layer = super::usd_layer::LayerWriter::new(&wcfg);
    let total = frames.len();
    let done = Mutex::new(0usize);
    let results: Vec<Result<(u32, bool)>> = frames
        .par_iter()
        .map(|rec| {
            let t = Instant::now();
            let ply = cache_of(run_dir, rec)?;
            if own && frame_matches(run_dir, rec, &ply)? {
                progress(&done, total, rec.frame, "unchanged", t);
                return Ok((rec.frame, false));
            }
            let (state, rest) = crate::io::ply::read_with_rest(
                &run_dir.join(&ply.path),
                &run_space,
                run_cfg.solver.rest_density as f32,
                codec,
            )?;
            if codec.is_some() && rest.is_none() {
                return Err(Error::InvalidInput(format!(
                    "frame {}: {} holds no rest positions",
                    rec.frame, ply.path
                )));
            }
            let written = writer.write(FrameJob {
                frame: rec.frame,
                state: Arc::new(state),
                skip_write: false,
                started: t,
                rest: rest.map(Arc::new),
            })?;
            let new = written
                .record
                .ok_or_else(|| Error::Runtime("export: frame not written".into()))?;
            match &out_manifest {
                None => check_same(rec, &new, &ply)?,
                Some(m) => record(&dest, m, new, &layer)?,
            }
            progress(&done, total, rec.frame, "written", t);
            Ok((rec.frame, true))
        })
        .collect();
    let mut summary = ExportSummary {
        dir: dest.root().to_path_buf(),
        written: Vec::new(),
        unchanged: Vec::new(),
    };
    let mut errors = Vec::new();
    for r in results {
        match r {
            Ok((f, true)) => summary.written.push(f),
            Ok((f, false)) => summary.unchanged.push(f),
            Err(e) => errors.push(e),
        }
    }
    if let Some(e) = errors.into_iter().next() {
        return Err(e);
    }
    match &out_manifest {
        Some(m) => {
            let m = reload(&dest, m)?;
            writer.finish_run(&m)?;
        }
        None => {
            if !summary.written.is_empty() {
                writer.finish_run(&manifest)?;
            }
            if layer.restore(run_dir, &manifest)? {
                eprintln!(
                    "export: {} re-made as recorded",
                    crate::export::usd::layer_name(&cfg.shot)
                );
            }
        }
    }
    Ok(summary)
}

fn progress(done: &Mutex<usize>, total: usize, frame: u32, what: &str, t: Instant) {
    let mut d = done.lock().unwrap_or_else(|e| e.into_inner());
    *d += 1;
    eprintln!(
        "export frame {frame}: {what} ({}/{total}, {:.0} ms)",
        *d,
        t.elapsed().as_secs_f64() * 1e3
    );
}

/// The frame's particle cache record, checked against the file on disk.
fn cache_of(run_dir: &Path, rec: &FrameRecord) -> Result<FileRecord> {
    let ply = rec
        .files
        .iter()
        .find(|f| f.path.ends_with(".ply"))
        .ok_or_else(|| {
            Error::InvalidInput(format!(
                "frame {}: no particle cache in the manifest",
                rec.frame
            ))
        })?;
    let path = run_dir.join(&ply.path);
    if !path.is_file() {
        return Err(Error::InvalidInput(format!(
            "frame {}: {} is missing",
            rec.frame, ply.path
        )));
    }
    let on_disk = file_record(run_dir, &path)?;
    if on_disk != *ply {
        return Err(Error::InvalidInput(format!(
            "frame {}: {} differs from the manifest (size or SHA-256)",
            rec.frame, ply.path
        )));
    }
    Ok(ply.clone())
}

/// Every file of the record but the cache is on disk with its recorded size and checksum.
fn frame_matches(run_dir: &Path, rec: &FrameRecord, ply: &FileRecord) -> Result<bool> {
    for f in rec.files.iter().filter(|f| *f != ply) {
        let path = run_dir.join(&f.path);
        if !path.is_file() || file_record(run_dir, &path)? != *f {
            return Ok(false);
        }
    }
    Ok(true)
}

/// A re-made frame of the run's own settings must be the recorded one, byte for byte.
fn check_same(rec: &FrameRecord, new: &FrameRecord, ply: &FileRecord) -> Result<()> {
    let want: Vec<&FileRecord> = rec.files.iter().filter(|f| *f != ply).collect();
    let got: Vec<&FileRecord> = new.files.iter().collect();
    if want != got {
        let differ: Vec<&str> = got
            .iter()
            .filter(|g| !want.contains(g))
            .map(|g| g.path.as_str())
            .collect();
        return Err(Error::Runtime(format!(
            "frame {}: re-made files differ from the run's record: {}",
            rec.frame,
            differ.join(", ")
        )));
    }
    Ok(())
}

/// Adds a frame to the export's manifest on disk, under the export directory's lock (other
/// processes may be exporting other frames into it).
fn record(
    dest: &RunDir,
    m: &Mutex<Manifest>,
    rec: FrameRecord,
    layer: &super::usd_layer::LayerWriter,
) -> Result<()> {
    let mut fresh = m.lock().unwrap_or_else(|e| e.into_inner());
    let lock = lock_file(dest)?;
    let mut current = match Manifest::load(dest) {
        Ok(on_disk) if on_disk.config == fresh.config => on_disk,
        _ => fresh.clone(),
    };
    current.record_frame(rec);
    current.complete =
        (current.frame_start..=current.frame_end).all(|f| current.frame(f).is_some());
    layer.update(dest.root(), &mut current)?;
    current.save(dest)?;
    *fresh = current;
    drop(lock);
    Ok(())
}

fn reload(dest: &RunDir, m: &Mutex<Manifest>) -> Result<Manifest> {
    let fresh = m.lock().unwrap_or_else(|e| e.into_inner()).clone();
    let _lock = lock_file(dest)?;
    Ok(Manifest::load(dest).unwrap_or(fresh))
}

/// Blocking exclusive lock of `dest/.lock`, released on drop.
fn lock_file(dest: &RunDir) -> Result<std::fs::File> {
    let path = dest.lock_file();
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|e| Error::io(&path, e))?;
    f.lock().map_err(|e| Error::io(&path, e))?;
    Ok(f)
}

/// `exports/<name>` under the run for `sets` (`--set export.key=value`) and `--name`, or `None`
/// when the sets leave the run's own export settings (the files then go to the run itself).
pub fn destination(run_dir: &Path, sets: &[String], name: Option<&str>) -> Result<Option<PathBuf>> {
    let run = RunDir::new(run_dir);
    let manifest = Manifest::load(&run)?;
    let run_cfg = shot_of(&manifest, run_dir, &[])?.into_config();
    let cfg = shot_of(&manifest, run_dir, sets)?.into_config();
    if cfg.export == run_cfg.export {
        return Ok(None);
    }
    Ok(Some(
        run.export_dir(&dir_name(&cfg, name)?).root().to_path_buf(),
    ))
}

fn dir_name(cfg: &ShotConfig, name: Option<&str>) -> Result<String> {
    match name {
        Some(n) => check_name(n),
        None => Ok(default_name(cfg)),
    }
}

pub fn check_name(n: &str) -> Result<String> {
    if n.is_empty()
        || n.len() > 100
        || n.starts_with('.')
        || !n
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c))
    {
        return Err(Error::InvalidInput(format!(
            "--name {n:?}: use 1-100 letters, digits, '.', '_' or '-', not starting with '.'"
        )));
    }
    Ok(n.to_string())
}

/// `x<12 hex>`: a hash of the resolved export settings.
fn default_name(cfg: &ShotConfig) -> String {
    let text = serde_json::to_string(&cfg.export).unwrap_or_default();
    format!("x{}", &super::records::sha256_hex(text.as_bytes())[..12])
}
