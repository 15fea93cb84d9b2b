//! `nimbus preview OUT_DIR`: (re)render the previews of a run from the VDB files it wrote, with
//! the camera and light of the given config (the run's own, possibly with `--set` overrides).
use super::naming::frame_file;
use super::records::Manifest;
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::io::vdb::{read::read_file, GridData};
use std::path::{Path, PathBuf};

/// Renders a preview for every frame of the manifest whose VDB file exists, then the contact
/// sheet; returns the number of frames rendered.
pub fn rerender_previews(run_dir: &Path, cfg: &ShotConfig) -> Result<usize> {
    let manifest = Manifest::load(run_dir)?;
    let params = crate::preview::PreviewParams::from_config(&cfg.output.preview, cfg.domain.size)?;
    let grid_name = &cfg.export.grids.density;
    let mut pngs: Vec<(u32, PathBuf)> = Vec::new();
    for rec in &manifest.frames {
        let vdb = frame_file(
            run_dir,
            "vdb",
            &cfg.shot,
            rec.frame,
            cfg.output.frame_padding,
            "vdb",
        );
        if !vdb.exists() {
            continue;
        }
        let file = read_file(&vdb)?;
        let grid = match file.grid(grid_name).map(|g| &g.data) {
            Some(GridData::Float(g)) => g,
            _ => {
                return Err(Error::InvalidInput(format!(
                    "{}: no float grid named '{grid_name}' (export.grids.density)",
                    vdb.display()
                )))
            }
        };
        let png = crate::preview::write_frame_preview(
            grid,
            &params,
            run_dir,
            &cfg.shot,
            rec.frame,
            cfg.output.frame_padding,
            cfg.output.preview.exr,
        )?;
        pngs.push((rec.frame, png));
    }
    if pngs.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: the run has no VDB frames to preview",
            run_dir.display()
        )));
    }
    crate::preview::write_contact_sheet(run_dir, &pngs)?;
    Ok(pngs.len())
}
