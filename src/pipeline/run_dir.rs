//! The run directory's layout (README "A run directory"): [`RunDir`] names every path in it,
//! so no other file writes a folder or file name of a run directory. What a directory holds,
//! and whether it can take a fresh run, is `super::survey`'s.
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// A run directory (or an export directory, `exports/<name>/`, which has the same layout
/// without checkpoints): the one place its file and folder names are written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunDir {
    root: PathBuf,
}

/// The kinds of per-frame file: `<folder>/<shot>.<frame, zero-padded>.<ext>`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameFile {
    Vdb,
    NanoVdb,
    Exr,
    PreviewPng,
    PreviewExr,
    Particles,
}

impl FrameFile {
    pub const ALL: [FrameFile; 6] = [
        FrameFile::Vdb,
        FrameFile::NanoVdb,
        FrameFile::Exr,
        FrameFile::PreviewPng,
        FrameFile::PreviewExr,
        FrameFile::Particles,
    ];

    /// The folder under the run directory.
    pub fn folder(self) -> &'static str {
        match self {
            FrameFile::Vdb => "vdb",
            FrameFile::NanoVdb => "nvdb",
            FrameFile::Exr => "exr",
            FrameFile::PreviewPng | FrameFile::PreviewExr => RunDir::PREVIEW,
            FrameFile::Particles => "particles",
        }
    }

    pub fn ext(self) -> &'static str {
        match self {
            FrameFile::Vdb => "vdb",
            FrameFile::NanoVdb => "nvdb",
            FrameFile::Exr | FrameFile::PreviewExr => "exr",
            FrameFile::PreviewPng => "png",
            FrameFile::Particles => "ply",
        }
    }
}

impl RunDir {
    /// The lock file (`super::lock`).
    pub const LOCK: &'static str = ".lock";
    /// The run's record for the farm (`super::records::Manifest`).
    pub const MANIFEST: &'static str = "manifest.json";
    /// One line of stats per written frame (`super::records::StatsLog`).
    pub const STATS: &'static str = "stats.jsonl";
    pub(super) const CHECKPOINTS: &'static str = "checkpoints";
    const PREVIEW: &'static str = "preview";
    pub(super) const EXPORTS: &'static str = "exports";
    const CONTACT_SHEET: &'static str = "contact_sheet.png";
    /// The farm's Blender renders (`nimbus farm --render`), written by its job scripts, not by
    /// nimbus: foreign to the survey.
    pub const RENDER: &'static str = "render";
    /// The folders made before the first frame: the frame folders written from the writer's
    /// first frame on (the particle and NanoVDB folders are made when first written), then
    /// the checkpoints'.
    const FRAME_DIRS: [&'static str; 3] = ["vdb", "exr", Self::PREVIEW];

    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn lock_file(&self) -> PathBuf {
        self.root.join(Self::LOCK)
    }

    pub fn manifest(&self) -> PathBuf {
        self.root.join(Self::MANIFEST)
    }

    pub fn stats(&self) -> PathBuf {
        self.root.join(Self::STATS)
    }

    pub fn checkpoints(&self) -> PathBuf {
        self.root.join(Self::CHECKPOINTS)
    }

    pub fn preview(&self) -> PathBuf {
        self.root.join(Self::PREVIEW)
    }

    /// `preview/<folder>/`, the images of a debug view of `nimbus preview --view`.
    pub fn preview_view(&self, folder: &str) -> PathBuf {
        self.preview().join(folder)
    }

    /// The contact sheet of the previews in `dir` (`preview/` or a view's folder).
    pub fn contact_sheet_in(dir: &Path) -> PathBuf {
        dir.join(Self::CONTACT_SHEET)
    }

    /// `preview/contact_sheet.png`.
    pub fn contact_sheet(&self) -> PathBuf {
        Self::contact_sheet_in(&self.preview())
    }

    /// `preview/<shot>.mp4`, the dailies (`output.preview.movie`).
    pub fn movie(&self, shot: &str) -> PathBuf {
        self.preview().join(format!("{shot}.mp4"))
    }

    /// `exports/<name>/`, a `nimbus export` directory.
    pub fn export_dir(&self, name: &str) -> RunDir {
        RunDir::new(self.root.join(Self::EXPORTS).join(name))
    }

    /// `<folder>/<shot>.<frame, zero-padded>.<ext>`
    pub fn frame_file(&self, kind: FrameFile, shot: &str, frame: u32, padding: u32) -> PathBuf {
        self.root
            .join(kind.folder())
            .join(frame_name(shot, frame, padding, kind.ext()))
    }

    /// `<dir>/<shot>.<frame, zero-padded>.png`, a preview image in `dir` (`preview/` or a
    /// view's folder).
    pub fn preview_frame_in(dir: &Path, shot: &str, frame: u32, padding: u32) -> PathBuf {
        dir.join(frame_name(
            shot,
            frame,
            padding,
            FrameFile::PreviewPng.ext(),
        ))
    }

    /// The frames of `kind` as an ffmpeg input pattern (`<shot>.%0<padding>d.<ext>`).
    pub fn frame_pattern(&self, kind: FrameFile, shot: &str, padding: u32) -> PathBuf {
        self.root
            .join(kind.folder())
            .join(format!("{shot}.%0{}d.{}", padding.max(1), kind.ext()))
    }

    /// `render/<shot>.<frame, zero-padded>.png`, a farm render of a frame.
    pub fn render_frame(&self, shot: &str, frame: u32, padding: u32) -> PathBuf {
        self.root
            .join(Self::RENDER)
            .join(frame_name(shot, frame, padding, "png"))
    }

    /// Makes the folders of the frame files (`vdb`, `exr`, `preview`) and, with `checkpoints`,
    /// `checkpoints` (an export directory has none).
    pub fn create_dirs(&self, checkpoints: bool) -> Result<()> {
        let extra = checkpoints.then_some(Self::CHECKPOINTS);
        for d in Self::FRAME_DIRS.into_iter().chain(extra) {
            let p = self.root.join(d);
            std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
        Ok(())
    }
}

/// `<shot>.<frame, zero-padded to padding digits>.<ext>`
fn frame_name(shot: &str, frame: u32, padding: u32, ext: &str) -> String {
    format!("{shot}.{frame:0width$}.{ext}", width = padding as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_follow_the_documented_layout() {
        let run = RunDir::new("out");
        let p = |s: &str| PathBuf::from(s);
        assert_eq!(
            run.frame_file(FrameFile::Vdb, "shot", 7, 4),
            p("out/vdb/shot.0007.vdb")
        );
        assert_eq!(
            run.frame_file(FrameFile::NanoVdb, "shot", 7, 4),
            p("out/nvdb/shot.0007.nvdb")
        );
        assert_eq!(
            run.frame_file(FrameFile::Exr, "shot", 12, 1),
            p("out/exr/shot.12.exr")
        );
        assert_eq!(
            run.frame_file(FrameFile::PreviewExr, "shot", 7, 4),
            p("out/preview/shot.0007.exr")
        );
        assert_eq!(
            run.frame_file(FrameFile::Particles, "shot", 7, 4),
            p("out/particles/shot.0007.ply")
        );
        assert_eq!(
            run.frame_pattern(FrameFile::PreviewPng, "shot", 4),
            p("out/preview/shot.%04d.png")
        );
        assert_eq!(run.manifest(), p("out/manifest.json"));
        assert_eq!(run.stats(), p("out/stats.jsonl"));
        assert_eq!(run.lock_file(), p("out/.lock"));
        assert_eq!(run.checkpoints(), p("out/checkpoints"));
        assert_eq!(run.contact_sheet(), p("out/preview/contact_sheet.png"));
        assert_eq!(run.movie("shot"), p("out/preview/shot.mp4"));
        assert_eq!(run.preview_view("target"), p("out/preview/target"));
        assert_eq!(
            RunDir::preview_frame_in(&run.preview_view("target"), "shot", 7, 4),
            p("out/preview/target/shot.0007.png")
        );
        assert_eq!(run.export_dir("a").root(), p("out/exports/a"));
        assert_eq!(run.render_frame("s", 3, 2), p("out/render/s.03.png"));
    }
}
