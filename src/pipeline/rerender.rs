//! `nimbus preview OUT_DIR`: (re)render the previews of a run from the VDB files it wrote, with
//! the camera and light of the given config (the run's own, possibly with `--set` overrides).
use super::lock::{Create, RunLock};
use super::naming::frame_file;
use super::records::{sha256_hex, FrameRecord, Manifest};
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::io::vdb::{read::read_file, GridData};
use std::path::{Path, PathBuf};

/// `nimbus preview RUN_DIR`: [`rerender_previews`] under the run directory's lock, with the
/// config the run recorded and the overrides `set`; returns the number of frames rendered.
pub fn rerender_run(run_dir: &Path, set: &[String]) -> Result<usize> {
    let _lock = RunLock::acquire(run_dir, Create::No, "preview")?;
    let cfg = super::resume::config_of_run(run_dir, set)?;
    rerender_previews(run_dir, &cfg)
}

/// Renders a preview for every frame of the manifest from its VDB file, after checking that
/// file against the manifest's size and SHA-256, then the contact sheet; returns the number of
/// frames rendered. A frame whose VDB is missing or is not the file the run wrote is reported on
/// stderr, its old preview files are removed (none is left looking current), and the command
/// fails (exit 2) after rendering the others.
pub fn rerender_previews(run_dir: &Path, cfg: &ShotConfig) -> Result<usize> {
    let manifest = Manifest::load(run_dir)?;
    let params = crate::preview::PreviewParams::from_config(&cfg.output.preview, cfg.domain.size)?;
    let grid_name = &cfg.export.grids.density;
    let space = crate::export::ExportSpace::from_config(cfg);
    let mut pngs: Vec<(u32, PathBuf)> = Vec::new();
    let mut failed: Vec<String> = Vec::new();
    for rec in &manifest.frames {
        let vdb = frame_file(
            run_dir,
            "vdb",
            &cfg.shot,
            rec.frame,
            cfg.output.frame_padding,
            "vdb",
        );
        if let Err(why) = check_recorded(run_dir, rec, &vdb) {
            eprintln!("frame {}: {why}", rec.frame);
            failed.push(format!("frame {}", rec.frame));
            remove_previews(run_dir, cfg, rec.frame)?;
            continue;
        }
        let file = read_file(&vdb)?;
        let grid = match file.grid(grid_name).map(|g| &g.data) {
            // The preview renders in nimbus's own frame (metres, y-up).
            Some(GridData::Float(g)) => space.float_grid_to_sim(g.clone()),
            _ => {
                return Err(Error::InvalidInput(format!(
                    "{}: no float grid named '{grid_name}' (export.grids.density)",
                    vdb.display()
                )))
            }
        };
        let png = crate::preview::write_frame_preview(
            &grid,
            &params,
            run_dir,
            &cfg.shot,
            rec.frame,
            cfg.output.frame_padding,
            cfg.output.preview.exr,
        )?;
        pngs.push((rec.frame, png));
    }
    let sheet = run_dir.join("preview").join("contact_sheet.png");
    if pngs.is_empty() {
        remove_if_present(&sheet)?;
        return Err(Error::InvalidInput(format!(
            "{}: the run has no VDB frames to preview{}",
            run_dir.display(),
            if failed.is_empty() {
                String::new()
            } else {
                format!(" ({} missing or changed, see above)", failed.len())
            }
        )));
    }
    crate::preview::write_contact_sheet(run_dir, &pngs)?;
    if !failed.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: {} of {} frames could not be previewed ({}); the others were rendered",
            run_dir.display(),
            failed.len(),
            manifest.frames.len(),
            failed.join(", ")
        )));
    }
    Ok(pngs.len())
}

/// The VDB of `rec` is on disk with the size and SHA-256 the manifest recorded.
fn check_recorded(
    run_dir: &Path,
    rec: &FrameRecord,
    vdb: &Path,
) -> std::result::Result<(), String> {
    let rel = vdb
        .strip_prefix(run_dir)
        .unwrap_or(vdb)
        .to_string_lossy()
        .replace('\\', "/");
    let Some(want) = rec.files.iter().find(|f| f.path == rel) else {
        return Err(format!("{rel}: not listed in the manifest"));
    };
    let bytes = match std::fs::read(vdb) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!("{rel}: missing"))
        }
        Err(e) => return Err(format!("{rel}: cannot read: {e}")),
    };
    if bytes.len() as u64 != want.bytes || sha256_hex(&bytes) != want.sha256 {
        return Err(format!(
            "{rel}: SHA-256 differs from the manifest (not the file the run wrote)"
        ));
    }
    Ok(())
}

fn remove_previews(run_dir: &Path, cfg: &ShotConfig, frame: u32) -> Result<()> {
    for ext in ["png", "exr"] {
        let p = frame_file(
            run_dir,
            "preview",
            &cfg.shot,
            frame,
            cfg.output.frame_padding,
            ext,
        );
        remove_if_present(&p)?;
    }
    Ok(())
}

fn remove_if_present(p: &Path) -> Result<()> {
    match std::fs::remove_file(p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(p, e)),
    }
}
