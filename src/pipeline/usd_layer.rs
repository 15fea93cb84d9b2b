//! The USD layer of a run or export directory (`export.usd`, `export::usd`) kept in step with
//! its manifest: rewritten atomically before the manifest is saved whenever its frames change
//! (a resumed or extended run adds its new frames), and recorded in the manifest (`usd`, with
//! size and SHA-256).
use super::records::{file_record, sha256_hex, FileRecord, Manifest};
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::export::usd::{layer_name, Layer};
use crate::export::{vdb_grid_names, ExportSpace, VdbGridName};
use std::path::Path;

/// What the layer of one shot's settings needs besides the frames.
#[derive(Debug, Clone)]
pub struct LayerWriter {
    enabled: bool,
    shot: String,
    grids: Vec<VdbGridName>,
    space: ExportSpace,
}

impl LayerWriter {
    pub fn new(cfg: &ShotConfig) -> Self {
        LayerWriter {
            enabled: cfg.export.usd,
            shot: cfg.shot.clone(),
            grids: vdb_grid_names(&cfg.export),
            space: ExportSpace::from_config(cfg),
        }
    }

    /// The layer's text for the frames `m` records (`None`: off, or no frame yet).
    fn text(&self, m: &Manifest) -> Option<String> {
        if !self.enabled {
            return None;
        }
        let frames: Vec<(u32, String)> = m
            .frames
            .iter()
            .filter_map(|f| {
                f.files
                    .iter()
                    .find(|r| r.path.starts_with("vdb/") && r.path.ends_with(".vdb"))
                    .map(|r| (f.frame, r.path.clone()))
            })
            .collect();
        Layer {
            shot: &self.shot,
            grids: &self.grids,
            space: &self.space,
            frames: &frames,
        }
        .text()
    }

    /// Writes the layer for `m`'s frames into `dir` (unless it is there already as recorded)
    /// and records it in `m`; call before `m.save(dir)`.
    pub fn update(&self, dir: &Path, m: &mut Manifest) -> Result<()> {
        let Some(text) = self.text(m) else {
            m.usd = None;
            return Ok(());
        };
        let rec = FileRecord {
            path: layer_name(&self.shot),
            bytes: text.len() as u64,
            sha256: sha256_hex(text.as_bytes()),
        };
        let path = dir.join(&rec.path);
        let intact = m.usd.as_ref() == Some(&rec)
            && std::fs::read(&path).is_ok_and(|b| b == text.as_bytes());
        if !intact {
            crate::io::atomic::write_atomic(&path, text.as_bytes())?;
        }
        m.usd = Some(rec);
        Ok(())
    }

    /// `nimbus export` with the run's own settings: the layer the manifest records is re-made
    /// when missing or damaged, and must come out as recorded. Returns whether it was written.
    pub fn restore(&self, dir: &Path, m: &Manifest) -> Result<bool> {
        let (Some(rec), Some(text)) = (&m.usd, self.text(m)) else {
            return Ok(false);
        };
        let path = dir.join(&rec.path);
        if path.is_file() && file_record(dir, &path)? == *rec {
            return Ok(false);
        }
        if text.len() as u64 != rec.bytes || sha256_hex(text.as_bytes()) != rec.sha256 {
            return Err(Error::Runtime(format!(
                "{}: the re-made USD layer differs from the run's record",
                path.display()
            )));
        }
        crate::io::atomic::write_atomic(&path, text.as_bytes())?;
        Ok(true)
    }
}
