//! `nimbus preview RUN_DIR --view particles`: the particles of each frame drawn as discs
//! coloured by adaptive level (`preview::particles`, paper Fig. 3), finer levels over coarser
//! ones, with a key to the levels, in the preview's camera, over a dark background. A frame's
//! particles come from its particle cache (`export.particles`) when the manifest records one
//! and it is the file the run wrote, else from the frame's checkpoint; a frame with neither is
//! skipped with a note, and a run with none at all is an input error before anything is
//! written.
use super::records::Manifest;
use super::rerender::{check_recorded, remove_if_present};
use super::run_dir::{FrameFile, RunDir};
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::ground::ParticleState;
use crate::preview::particles::{draw_level_legend, render_levels};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Linear grey behind the particles.
const BACKGROUND: f32 = 0.02;

/// Where a frame's particles are read from.
enum Source {
    Cache(PathBuf),
    Checkpoint(PathBuf),
}

/// Renders the view of every frame that has particles into `dir` and its contact sheet;
/// returns the number of frames rendered.
pub fn render(run_dir: &Path, cfg: &ShotConfig, dir: &Path) -> Result<usize> {
    let run = RunDir::new(run_dir);
    let manifest = Manifest::load(&run)?;
    let params = crate::preview::PreviewParams::for_shot(cfg)?;
    let pad = cfg.output.frame_padding;
    let checkpoints: BTreeMap<u32, PathBuf> =
        crate::io::checkpoint::list_checkpoints(&run.checkpoints())?
            .into_iter()
            .collect();
    let mut plan: Vec<(u32, Option<Source>)> = Vec::new();
    for rec in &manifest.frames {
        let ply = run.frame_file(FrameFile::Particles, &cfg.shot, rec.frame, pad);
        let source = if check_recorded(run_dir, rec, &ply).is_ok() {
            Some(Source::Cache(ply))
        } else {
            checkpoints
                .get(&rec.frame)
                .map(|p| Source::Checkpoint(p.clone()))
        };
        plan.push((rec.frame, source));
    }
    if plan.iter().all(|(_, s)| s.is_none()) {
        return Err(Error::InvalidInput(format!(
            "{}: --view particles: the run has no particle caches (export.particles) and no checkpoint of a recorded frame to draw particles from",
            run_dir.display()
        )));
    }
    let space = crate::export::ExportSpace::from_config(cfg);
    let h0 = cfg.domain.kernel_radius();
    let max_level = if cfg.adaptive.enabled {
        cfg.adaptive.max_level
    } else {
        0
    };
    let mut pngs = Vec::new();
    let mut skipped = Vec::new();
    for (frame, source) in plan {
        let png = RunDir::preview_frame_in(dir, &cfg.shot, frame, pad);
        let state: ParticleState = match source {
            Some(Source::Cache(p)) => {
                crate::io::ply::read(&p, &space, cfg.solver.rest_density as f32)?
            }
            Some(Source::Checkpoint(p)) => crate::io::checkpoint::read_checkpoint(&p)?.state,
            None => {
                skipped.push(frame);
                remove_if_present(&png)?;
                continue;
            }
        };
        let mut img = render_levels(&state, &params, h0, max_level)?;
        // A dark background: level 0's blue would hardly stand out from the sky.
        for px in img.data.iter_mut().filter(|px| px[3] == 0.0) {
            *px = [BACKGROUND, BACKGROUND, BACKGROUND, 0.0];
        }
        let mut rgb = img.to_srgb8_standard();
        draw_level_legend(&mut rgb, max_level);
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        crate::io::atomic::write_atomic(&png, &crate::preview::png_bytes(&rgb)?)?;
        pngs.push((frame, png));
    }
    if !skipped.is_empty() {
        eprintln!(
            "note: no particle cache or checkpoint for frame{} {}; skipped",
            if skipped.len() == 1 { "" } else { "s" },
            super::naming::frame_ranges(&skipped)
        );
    }
    crate::preview::sheet::write_contact_sheet(&RunDir::contact_sheet_in(dir), &pngs)?;
    Ok(pngs.len())
}
