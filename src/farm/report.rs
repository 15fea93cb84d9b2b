//! `nimbus farm report`: the farm's last job. Checks every frame of every wedge against its
//! run's manifest (each file's size and SHA-256), and with an export stage every exported frame
//! against its export directory's manifest, the USD layers those manifests record too, and
//! writes `farm_report.json` and the wedge contact sheet. Run again at any time; it only reads
//! the runs.
use super::plan::{run_dir, ExportSettings, FarmPlan, REPORT, SHEET};
use super::sheet::{self, SheetRow};
use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use crate::pipeline::records::{sha256_hex, FrameRecord, Manifest};
use crate::pipeline::reexport;
use crate::pipeline::run_dir::RunDir;
use serde::Serialize;
use std::path::Path;

/// Preview frames shown per wedge on the sheet.
const SHEET_FRAMES: usize = 6;

#[derive(Debug, Serialize)]
pub struct WedgeReport {
    pub index: usize,
    pub name: String,
    pub values: Vec<(String, String)>,
    pub run_dir: String,
    pub manifest_complete: bool,
    pub frames_expected: u32,
    pub frames_verified: u32,
    pub files_verified: u64,
    pub bytes_verified: u64,
    /// Frames of the range the manifest does not record.
    pub missing_frames: Vec<u32>,
    /// `path: why` for every file that does not match its record.
    pub bad_files: Vec<String>,
    pub error: Option<String>,
    /// With `--render`: frames whose `render/<shot>.<frame>.png` exists (PNG signature checked).
    pub frames_rendered: Option<u32>,
    /// With an export stage: the wedge's `exports/<name>/` directory and the frames its manifest
    /// records whose files all match that manifest (sizes, SHA-256).
    pub export_dir: Option<String>,
    pub frames_exported: Option<u32>,
    /// The run's USD layer (`export.usd`) and the export directory's, when their manifests
    /// record one, checked like the frames (size, SHA-256).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub usd_layer: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub export_usd_layer: Option<String>,
    pub complete: bool,
}

#[derive(Debug, Serialize)]
pub struct FarmReport {
    pub tool: String,
    pub version: String,
    pub shot: String,
    pub frame_start: u32,
    pub frame_end: u32,
    pub wedges: Vec<WedgeReport>,
    pub contact_sheet: Option<String>,
    /// Every wedge complete and every file verified.
    pub complete: bool,
}

/// Verifies the runs, writes the report and sheet; Ok even when the farm is incomplete (the
/// report says so), Err only when the report itself cannot be written.
pub fn report(farm_dir: &Path) -> Result<FarmReport> {
    let plan = FarmPlan::load(farm_dir)?;
    let mut wedges = Vec::new();
    let mut rows = Vec::new();
    for w in &plan.wedges {
        let dir = run_dir(farm_dir, w);
        let (rep, previews) = verify_run(&plan, &dir);
        wedges.push(WedgeReport {
            index: w.index,
            name: w.name.clone(),
            values: w.values.clone(),
            run_dir: dir.display().to_string(),
            ..rep
        });
        let mut frames = Vec::new();
        let numbers: Vec<u32> = previews.iter().map(|(f, _)| *f).collect();
        for f in sheet::pick_frames(&numbers, SHEET_FRAMES) {
            let Some((_, p)) = previews.iter().find(|(n, _)| *n == f) else {
                continue;
            };
            if let Ok(img) = image::open(dir.join(p)) {
                frames.push((f, img.to_rgb8()));
            }
        }
        rows.push(SheetRow {
            label: format!("{}: {}", w.name, w.label()),
            frames,
        });
    }
    let sheet_path = farm_dir.join(SHEET);
    let contact_sheet = match sheet::write_wedge_sheet(&sheet_path, &rows) {
        Ok(()) => Some(sheet_path.display().to_string()),
        // No previews anywhere (output.preview.enabled: false): the report says so.
        Err(Error::InvalidInput(_)) => None,
        Err(e) => return Err(e),
    };
    let complete = !wedges.is_empty() && wedges.iter().all(|w| w.complete);
    let report = FarmReport {
        tool: "nimbus".into(),
        version: crate::VERSION.into(),
        shot: plan.shot.clone(),
        frame_start: plan.frame_start,
        frame_end: plan.frame_end,
        wedges,
        contact_sheet,
        complete,
    };
    let mut text =
        serde_json::to_string_pretty(&report).map_err(|e| Error::Runtime(e.to_string()))?;
    text.push('\n');
    write_atomic(&farm_dir.join(REPORT), text.as_bytes())?;
    Ok(report)
}

/// One run checked against its manifest, and its preview PNGs (frame, path in the run).
fn verify_run(plan: &FarmPlan, dir: &Path) -> (WedgeReport, Vec<(u32, String)>) {
    let expected = plan.frame_end - plan.frame_start + 1;
    let mut rep = WedgeReport {
        index: 0,
        name: String::new(),
        values: Vec::new(),
        run_dir: String::new(),
        manifest_complete: false,
        frames_expected: expected,
        frames_verified: 0,
        files_verified: 0,
        bytes_verified: 0,
        missing_frames: Vec::new(),
        bad_files: Vec::new(),
        error: None,
        frames_rendered: None,
        export_dir: None,
        frames_exported: None,
        usd_layer: None,
        export_usd_layer: None,
        complete: false,
    };
    let manifest = match Manifest::load(&RunDir::new(dir)) {
        Ok(m) => m,
        Err(e) => {
            rep.error = Some(e.to_string());
            rep.missing_frames = (plan.frame_start..=plan.frame_end).collect();
            return (rep, Vec::new());
        }
    };
    rep.manifest_complete = manifest.complete;
    let mut previews = Vec::new();
    for frame in plan.frame_start..=plan.frame_end {
        let Some(rec) = manifest.frame(frame) else {
            rep.missing_frames.push(frame);
            continue;
        };
        if verify_frame(dir, "", rec, &mut rep, Some((frame, &mut previews))) {
            rep.frames_verified += 1;
        }
    }
    let layer_ok = verify_layer(dir, "", &manifest, &mut rep).map(|(path, ok)| {
        rep.usd_layer = Some(path);
        ok
    });
    rep.complete =
        rep.manifest_complete && rep.frames_verified == expected && layer_ok != Some(false);
    if let Some(e) = &plan.export {
        let exported = verify_export(plan, dir, e, &mut rep);
        rep.frames_exported = Some(exported);
        rep.complete &= exported == expected;
    }
    if let Some(r) = &plan.render {
        let rendered = (plan.frame_start..=plan.frame_end)
            .filter(|f| {
                let png = RunDir::new(dir).render_frame(&plan.shot, *f, r.frame_padding);
                std::fs::read(png).is_ok_and(|b| b.starts_with(b"\x89PNG\r\n\x1a\n"))
            })
            .count() as u32;
        rep.frames_rendered = Some(rendered);
        rep.complete &= rendered == expected;
    }
    (rep, previews)
}

/// Every file of a frame record on disk with its recorded size and SHA-256; what does not match
/// goes to `bad_files` (named `prefix` + path), previews to `previews`.
fn verify_frame(
    dir: &Path,
    prefix: &str,
    rec: &FrameRecord,
    rep: &mut WedgeReport,
    mut previews: Option<(u32, &mut Vec<(u32, String)>)>,
) -> bool {
    let mut ok = !rec.files.is_empty();
    for f in &rec.files {
        let path = dir.join(&f.path);
        match std::fs::read(&path) {
            Ok(b) if b.len() as u64 != f.bytes => {
                ok = false;
                rep.bad_files.push(format!(
                    "{prefix}{}: {} bytes, the manifest records {}",
                    f.path,
                    b.len(),
                    f.bytes
                ));
            }
            Ok(b) if sha256_hex(&b) != f.sha256 => {
                ok = false;
                rep.bad_files.push(format!(
                    "{prefix}{}: SHA-256 differs from the manifest's",
                    f.path
                ));
            }
            Ok(b) => {
                rep.files_verified += 1;
                rep.bytes_verified += b.len() as u64;
                if let Some((frame, previews)) = previews.as_mut() {
                    if f.path.starts_with("preview/") && f.path.ends_with(".png") {
                        previews.push((*frame, f.path.clone()));
                    }
                }
            }
            Err(e) => {
                ok = false;
                rep.bad_files.push(format!("{prefix}{}: {e}", f.path));
            }
        }
    }
    ok
}

/// The wedge's export directory checked against its own manifest: frames whose files all match.
fn verify_export(plan: &FarmPlan, dir: &Path, e: &ExportSettings, rep: &mut WedgeReport) -> u32 {
    let dest = match reexport::destination(dir, &e.sets, e.name.as_deref()) {
        Ok(Some(d)) => d,
        Ok(None) => {
            rep.error = Some("the export settings are the run's own: no export directory".into());
            return 0;
        }
        Err(err) => {
            rep.error.get_or_insert(format!("export: {err}"));
            return 0;
        }
    };
    let prefix = dest
        .strip_prefix(dir)
        .map(|p| format!("{}/", p.display()))
        .unwrap_or_default();
    rep.export_dir = Some(dest.display().to_string());
    let manifest = match Manifest::load(&RunDir::new(&dest)) {
        Ok(m) => m,
        Err(err) => {
            rep.error.get_or_insert(format!("export: {err}"));
            return 0;
        }
    };
    let mut exported = 0;
    for frame in plan.frame_start..=plan.frame_end {
        if let Some(rec) = manifest.frame(frame) {
            if verify_frame(&dest, &prefix, rec, rep, None) {
                exported += 1;
            }
        }
    }
    if let Some((path, ok)) = verify_layer(&dest, &prefix, &manifest, rep) {
        rep.export_usd_layer = Some(format!("{prefix}{path}"));
        rep.complete &= ok;
    }
    exported
}

/// The USD layer a manifest records, checked against the file (size, SHA-256): its path and
/// whether it matches; `None` when the manifest records none.
fn verify_layer(
    dir: &Path,
    prefix: &str,
    m: &Manifest,
    rep: &mut WedgeReport,
) -> Option<(String, bool)> {
    let rec = m.usd.as_ref()?;
    let as_frame = FrameRecord {
        frame: 0,
        files: vec![rec.clone()],
    };
    let ok = verify_frame(dir, prefix, &as_frame, rep, None);
    Some((rec.path.clone(), ok))
}
