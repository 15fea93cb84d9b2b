//! What a run directory holds, and preparing one for a fresh `run` without losing work.
//!
//! nimbus's own files in a run directory are: `.lock`; `manifest.json` when it parses as a
//! nimbus manifest; then, by that manifest, every file it lists, every frame file named by its
//! shot (the shot the newest checkpoint records when the manifest is lost) (`vdb/<shot>.<digits>.vdb`, `exr/<shot>.<digits>.exr`, `preview/<shot>.<digits>.png|exr`, `particles/<shot>.<digits>.ply`,
//! `nvdb/<shot>.<digits>.nvdb`; a frame written just before a kill is not listed yet),
//! `preview/contact_sheet.png`, `preview/<shot>.mp4` and the USD layer `<shot>.usda`;
//! `stats.jsonl` when the manifest is nimbus's or every line is a stats line; checkpoint files
//! (`checkpoints/ckpt_<digits>.nck` starting with the checkpoint magic); and temporary files
//! (`*.nimbus-tmp`, stale once the lock is held); and under `exports/<name>/` (`nimbus
//! export`) what the same rules make own by that directory's manifest. Everything else is
//! foreign.
//!
//! A fresh `run` into a directory holding a run is refused (resume it, or `--force`); with
//! `--force` only nimbus's own files are removed. A directory holding any foreign file is
//! refused with or without `--force`: nothing nimbus did not write is ever deleted.
use super::lock;
use super::naming::resume_command;
use super::records::{Manifest, StatsLine};
use super::run_dir::{FrameFile, RunDir};
use crate::error::{Error, Result};
use crate::io::atomic::TMP_SUFFIX;
use crate::io::checkpoint;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The files of a run directory, sorted into nimbus's own and foreign ones (paths relative to
/// the directory, `/`-separated).
#[derive(Debug, Default)]
pub struct Contents {
    pub own: Vec<String>,
    pub foreign: Vec<String>,
    /// The manifest, when it is nimbus's.
    pub manifest: Option<Manifest>,
    /// Frames of the checkpoint files found.
    pub checkpoints: Vec<u32>,
}

impl Contents {
    /// Whether the directory holds (part of) a nimbus run: a manifest, checkpoints or stats.
    pub fn holds_run(&self) -> bool {
        self.manifest.is_some()
            || !self.checkpoints.is_empty()
            || self.own.iter().any(|p| p == RunDir::STATS)
    }
}

/// Sorts every file under `dir` (symlinks are not followed, and are foreign).
pub fn survey(dir: &Path) -> Result<Contents> {
    let files = walk(dir)?;
    let run = RunDir::new(dir);
    let mut c = Contents {
        manifest: Manifest::load(&run).ok().filter(|m| m.tool == "nimbus"),
        ..Default::default()
    };
    // The shot whose frame files are nimbus's: the manifest's, or (manifest lost) the one the
    // newest checkpoint records.
    let shot = match &c.manifest {
        Some(m) => Some(m.shot.clone()),
        None => checkpoint::newest_config(&run.checkpoints())?.map(|(_, cfg)| cfg.shot),
    };
    let listed: BTreeSet<&str> = c
        .manifest
        .iter()
        .flat_map(|m| m.frames.iter())
        .flat_map(|f| f.files.iter().map(|r| r.path.as_str()))
        .collect();
    // `nimbus export` directories (`exports/<name>/`) are surveyed the same way, by their own
    // manifests.
    let mut exported: BTreeSet<String> = BTreeSet::new();
    if let Ok(entries) = std::fs::read_dir(dir.join(RunDir::EXPORTS)) {
        for e in entries.flatten() {
            let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
            if let (true, Some(name)) = (is_dir, e.file_name().to_str()) {
                for r in survey(&e.path())?.own {
                    exported.insert(format!("exports/{name}/{r}"));
                }
            }
        }
    }
    let mut own = Vec::new();
    let mut foreign = Vec::new();
    for (rel, is_file) in files {
        let mine = is_file
            && (exported.contains(&rel)
                || rel == RunDir::LOCK
                || rel.ends_with(TMP_SUFFIX)
                || (rel == RunDir::MANIFEST && c.manifest.is_some())
                || (rel == RunDir::STATS && (c.manifest.is_some() || stats_only(&run.stats())))
                || listed.contains(rel.as_str())
                || shot.as_ref().is_some_and(|s| frame_file_of(&run, s, &rel))
                || own_checkpoint(&run, &rel, &mut c.checkpoints));
        if mine {
            own.push(rel);
        } else {
            foreign.push(rel);
        }
    }
    c.own = own;
    c.foreign = foreign;
    Ok(c)
}

/// Makes `dir` (locked by the caller) ready for a fresh run: nothing to do when it holds no
/// files; refused when it holds a run (unless `force`: then that run's files are removed) or
/// any foreign file.
pub fn prepare_fresh(dir: &Path, force: bool) -> Result<()> {
    let c = check_fresh(dir, force)?;
    let mut removed = 0;
    for rel in &c.own {
        if rel == RunDir::LOCK {
            continue;
        }
        let p = dir.join(rel);
        std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
        removed += 1;
    }
    if removed > 0 {
        eprintln!(
            "note: removed {removed} file(s) of an earlier run in {}",
            dir.display()
        );
    }
    Ok(())
}

/// Whether `out` can take a fresh run, read only: a file there, a directory another nimbus
/// process holds, files nimbus did not write, or an earlier run without `force` are refused
/// (exit 2). `run` asks it before it opens the
/// device, so that bad input is exit 2 on a machine without a GPU too, and `prepare_fresh`
/// again under the lock. A missing `out` passes (the lock creates it).
pub fn check_fresh_out(out: &Path, force: bool) -> Result<()> {
    match std::fs::metadata(out) {
        Ok(m) if m.is_dir() => {
            lock::check_not_in_use(out)?;
            check_fresh(out, force).map(|_| ())
        }
        Ok(_) => Err(Error::InvalidInput(format!(
            "{}: is a file, not a run directory",
            out.display()
        ))),
        Err(_) => Ok(()),
    }
}

/// The survey of `dir` when it may take a fresh run (see [`prepare_fresh`]).
fn check_fresh(dir: &Path, force: bool) -> Result<Contents> {
    let c = survey(dir)?;
    if !c.foreign.is_empty() {
        let shown: Vec<&str> = c.foreign.iter().take(3).map(String::as_str).collect();
        let more = c.foreign.len().saturating_sub(shown.len());
        return Err(Error::InvalidInput(format!(
            "{}: holds {} file(s) nimbus did not write ({}{}); a run goes into a new or empty \
             directory or over its own earlier run, and nimbus never deletes other files: \
             choose another --out",
            dir.display(),
            c.foreign.len(),
            shown.join(", "),
            if more > 0 {
                format!(", and {more} more")
            } else {
                String::new()
            }
        )));
    }
    if c.holds_run() && !force {
        let what = match &c.manifest {
            Some(m) => format!(
                "shot '{}', {} of frames {}..={} written{}",
                m.shot,
                m.frames.len(),
                m.frame_start,
                m.frame_end,
                if m.complete { ", complete" } else { "" }
            ),
            None => "no manifest".into(),
        };
        let ck = match c.checkpoints.iter().max() {
            Some(f) => format!(", newest checkpoint frame {f}"),
            None => String::new(),
        };
        return Err(Error::InvalidInput(format!(
            "{d}: already holds a nimbus run ({what}{ck}); to go on with it: {resume}; to start \
             over, deleting that run's files: add --force",
            d = dir.display(),
            resume = resume_command(dir)
        )));
    }
    Ok(c)
}

/// `<folder>/<shot>.<digits>.<ext>` of a [`FrameFile`] kind, the contact sheet, the movie or
/// the USD layer of `shot`.
fn frame_file_of(run: &RunDir, shot: &str, rel: &str) -> bool {
    let is = |p: PathBuf| {
        p.strip_prefix(run.root())
            .is_ok_and(|r| r == Path::new(rel))
    };
    if is(run.contact_sheet()) || is(run.movie(shot)) || rel == crate::export::usd::layer_name(shot)
    {
        return true;
    }
    let Some((folder, name)) = rel.split_once('/') else {
        return false;
    };
    let Some(rest) = name.strip_prefix(shot).and_then(|r| r.strip_prefix('.')) else {
        return false;
    };
    let Some((digits, ext)) = rest.split_once('.') else {
        return false;
    };
    !digits.is_empty()
        && digits.bytes().all(|b| b.is_ascii_digit())
        && FrameFile::ALL
            .iter()
            .any(|k| k.folder() == folder && k.ext() == ext)
}

fn own_checkpoint(run: &RunDir, rel: &str, frames: &mut Vec<u32>) -> bool {
    let Some(name) = rel
        .strip_prefix(RunDir::CHECKPOINTS)
        .and_then(|r| r.strip_prefix('/'))
    else {
        return false;
    };
    let Some(frame) = checkpoint::frame_of_name(name) else {
        return false;
    };
    let mut head = [0u8; 8];
    let ok = std::fs::File::open(run.root().join(rel))
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok()
        && checkpoint::is_checkpoint(&head);
    if ok {
        frames.push(frame);
    }
    ok
}

/// Whether every line of the file is a nimbus stats line (an empty file is).
fn stats_only(p: &Path) -> bool {
    std::fs::read_to_string(p).is_ok_and(|t| {
        t.lines()
            .all(|l| serde_json::from_str::<StatsLine>(l).is_ok())
    })
}

/// (relative path, is a regular file) of everything below `dir` but directories.
fn walk(dir: &Path) -> Result<Vec<(String, bool)>> {
    let mut out = Vec::new();
    let mut stack: Vec<PathBuf> = vec![PathBuf::new()];
    while let Some(rel) = stack.pop() {
        let abs = dir.join(&rel);
        let rd = std::fs::read_dir(&abs).map_err(|e| Error::io(&abs, e))?;
        for entry in rd {
            let entry = entry.map_err(|e| Error::io(&abs, e))?;
            let ft = entry.file_type().map_err(|e| Error::io(entry.path(), e))?;
            let r = rel.join(entry.file_name());
            if ft.is_dir() {
                stack.push(r);
            } else {
                out.push((r.to_string_lossy().replace('\\', "/"), ft.is_file()));
            }
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_files_follow_the_naming() {
        let run = RunDir::new("out");
        let of = |rel| frame_file_of(&run, "tiny", rel);
        assert!(of("vdb/tiny.0003.vdb"));
        assert!(of("preview/tiny.0003.exr"));
        assert!(of("preview/contact_sheet.png"));
        assert!(of("preview/tiny.mp4"));
        assert!(!of("vdb/tiny.0003.exr"));
        assert!(!of("vdb/other.0003.vdb"));
        assert!(!of("vdb/tiny.x3.vdb"));
        assert!(!of("notes/tiny.0003.vdb"));
    }

    #[test]
    fn empty_and_new_dirs_are_ready() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("vdb")).unwrap();
        std::fs::write(dir.path().join(RunDir::LOCK), "").unwrap();
        prepare_fresh(dir.path(), false).unwrap();
    }

    #[test]
    fn foreign_files_refuse_even_with_force_and_stay() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("checkpoints")).unwrap();
        let f = dir.path().join("checkpoints/notes.txt");
        std::fs::write(&f, "mine").unwrap();
        let e = prepare_fresh(dir.path(), true).unwrap_err();
        assert!(e.to_string().contains("checkpoints/notes.txt"), "{e}");
        assert_eq!(std::fs::read(&f).unwrap(), b"mine");
    }
}
