//! `nimbus preview OUT_DIR [--view V]`: (re)render the previews of a run from the files it
//! wrote, with the camera and light of the given config (the run's own, possibly with `--set`
//! overrides). The `volume` view re-makes the run's own previews in `preview/`; the debug views
//! draw what explains the cloud into `preview/<view>/` (same file names, a contact sheet of
//! their own), so the run's previews are never overwritten: `sources` and `target` over the
//! cloud rendered from the VDB files, `particles` from the particle caches or checkpoints
//! (`super::particle_view`).
use super::lock::{Create, RunLock};
use super::records::{sha256_hex, FrameRecord, Manifest};
use super::run_dir::{FrameFile, RunDir};
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::io::vdb::{read::read_file, GridData};
use crate::preview::overlay::{draw_domain_box, sources::SourceOverlay, target::TargetGhost};
use crate::preview::LinearImage;
use crate::shot::Shot;
use std::path::{Path, PathBuf};

/// What `nimbus preview` draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum View {
    /// The cloud, as the run's previews (`preview/`).
    Volume,
    /// The cloud with the heat sources' footprints and wireframes (`preview/sources/`).
    Sources,
    /// The cloud with the control target as a ghost (`preview/target/`).
    Target,
    /// The particles coloured by adaptive level (`preview/particles/`).
    Particles,
}

impl View {
    /// The folder under `preview/` a debug view writes to (none for `volume`).
    pub fn folder(self) -> Option<&'static str> {
        match self {
            View::Volume => None,
            View::Sources => Some("sources"),
            View::Target => Some("target"),
            View::Particles => Some("particles"),
        }
    }
}

/// `nimbus preview RUN_DIR --view V`: the view's images under the run directory's lock, with the
/// config the run recorded and the overrides `set`; returns the number of frames rendered and
/// the folder they are in. A view that has nothing to draw (no sources, no target, no particle
/// files) is an input error before anything is written.
pub fn rerender_run(run_dir: &Path, set: &[String], view: View) -> Result<(usize, PathBuf)> {
    let _lock = RunLock::acquire(run_dir, Create::No, "preview")?;
    let shot = super::resume::shot_of_run(run_dir, set)?;
    let cfg = shot.config().clone();
    let run = RunDir::new(run_dir);
    let dir = match view.folder() {
        Some(f) => run.preview_view(f),
        None => run.preview(),
    };
    let refused = |what: &str| {
        Error::InvalidInput(format!(
            "{}: --view {}: {what}",
            run_dir.display(),
            view.folder().unwrap_or("volume")
        ))
    };
    let n = match view {
        View::Volume => rerender_previews(run_dir, &shot)?,
        View::Sources => {
            if cfg.physics.sources.is_empty() {
                return Err(refused("the run has no physics.sources"));
            }
            let overlay = SourceOverlay::new(&cfg, shot.heat_maps())?;
            let draw = |img: &mut LinearImage, frame: u32, p: &_| {
                draw_domain_box(img, p, cfg.domain.size);
                overlay.draw(img, p, frame)
            };
            rerender_into(run_dir, &cfg, &dir, false, Some(&draw))?
        }
        View::Target => {
            let Some(target) = shot.target() else {
                return Err(refused("the run has no control.target"));
            };
            let ghost = TargetGhost::new(target);
            let draw = |img: &mut LinearImage, _: u32, p: &_| {
                draw_domain_box(img, p, cfg.domain.size);
                ghost.draw(img, p)
            };
            rerender_into(run_dir, &cfg, &dir, false, Some(&draw))?
        }
        View::Particles => super::particle_view::render(run_dir, &cfg, &dir)?,
    };
    Ok((n, dir))
}

/// Draws into a frame's rendered image (its frame number, the camera and light).
type Decorate<'a> = &'a dyn Fn(&mut LinearImage, u32, &crate::preview::PreviewParams);

/// Renders a preview for every frame of the manifest from its VDB file, after checking that
/// file against the manifest's size and SHA-256, then the contact sheet; returns the number of
/// frames rendered. A frame whose VDB is missing or is not the file the run wrote is reported on
/// stderr, its old preview files are removed (none is left looking current), and the command
/// fails (exit 2) after rendering the others. With `output.preview.source_overlay` the sources
/// are drawn in, as the run drew them.
pub fn rerender_previews(run_dir: &Path, shot: &Shot) -> Result<usize> {
    let cfg = shot.config();
    let dir = RunDir::new(run_dir).preview();
    let exr = cfg.output.preview.exr;
    if cfg.output.preview.source_overlay {
        let overlay = SourceOverlay::new(cfg, shot.heat_maps())?;
        let draw = |img: &mut LinearImage, frame: u32, p: &_| overlay.draw(img, p, frame);
        rerender_into(run_dir, cfg, &dir, exr, Some(&draw))
    } else {
        rerender_into(run_dir, cfg, &dir, exr, None)
    }
}

/// [`rerender_previews`] into `dir`, each image passed through `decorate` before it is written.
fn rerender_into(
    run_dir: &Path,
    cfg: &ShotConfig,
    dir: &Path,
    exr: bool,
    decorate: Option<Decorate>,
) -> Result<usize> {
    let run = RunDir::new(run_dir);
    let manifest = Manifest::load(&run)?;
    let params = crate::preview::PreviewParams::for_shot(cfg)?;
    let grid_name = &cfg.export.grids.density;
    let space = crate::export::ExportSpace::from_config(cfg);
    let pad = cfg.output.frame_padding;
    let mut pngs: Vec<(u32, PathBuf)> = Vec::new();
    let mut failed: Vec<String> = Vec::new();
    for rec in &manifest.frames {
        let vdb = run.frame_file(FrameFile::Vdb, &cfg.shot, rec.frame, pad);
        let png = RunDir::preview_frame_in(dir, &cfg.shot, rec.frame, pad);
        if let Err(why) = check_recorded(run_dir, rec, &vdb) {
            eprintln!("frame {}: {why}", rec.frame);
            failed.push(format!("frame {}", rec.frame));
            remove_if_present(&png)?;
            remove_if_present(&png.with_extension("exr"))?;
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
        let mut img = crate::preview::render(&grid, &params)?;
        if let Some(draw) = decorate {
            draw(&mut img, rec.frame, &params);
        }
        let png = crate::preview::write_image(&img, params.exposure, &png, exr)?;
        pngs.push((rec.frame, png));
    }
    let sheet = RunDir::contact_sheet_in(dir);
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
    crate::preview::sheet::write_contact_sheet(&sheet, &pngs)?;
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
pub(crate) fn check_recorded(
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

pub(crate) fn remove_if_present(p: &Path) -> Result<()> {
    match std::fs::remove_file(p) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(p, e)),
    }
}
