//! Atomic file writes: write a temporary file beside the target, fsync, rename. A reader never
//! sees half a file, and a failed write leaves the previous file in place. Temporary files left
//! by a process that died are swept with [`remove_temp_files`].
use crate::error::{Error, Result};
use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Suffix of temporary files; leftovers with it are cleaned under the run-directory lock.
pub const TMP_SUFFIX: &str = ".nimbus-tmp";

/// A fresh temporary name beside `path`, unique per process and call:
/// `<name>.<pid>-<random hex>.nimbus-tmp`.
pub fn tmp_path(path: &Path) -> PathBuf {
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    // RandomState is seeded from the OS once per process; the counter makes each call differ.
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(COUNTER.fetch_add(1, Ordering::Relaxed));
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(
        ".{}-{:016x}{TMP_SUFFIX}",
        std::process::id(),
        h.finish()
    ));
    path.with_file_name(name)
}

/// Writes `bytes` to `path` atomically (temp + fsync + rename + directory fsync).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |f| f.write_all(bytes))
}

/// `write_atomic_with` through a 1 MiB buffer: `fill` writes the content in pieces.
pub fn write_atomic_buffered(
    path: &Path,
    fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> Result<()> {
    write_atomic_with(path, |f| {
        let mut w = std::io::BufWriter::with_capacity(1 << 20, f);
        fill(&mut w)?;
        std::io::Write::flush(&mut w)
    })
}

/// Like `write_atomic`, with the content produced by `fill` into the temporary file.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut File) -> std::io::Result<()>,
) -> Result<()> {
    let tmp = tmp_path(path);
    let result = (|| -> std::io::Result<()> {
        let mut f = File::create(&tmp)?;
        fill(&mut f)?;
        f.sync_all()?;
        drop(f);
        crate::fault::before_rename(path);
        fs::rename(&tmp, path)?;
        if let Some(dir) = path.parent() {
            // Persist the rename itself; not every filesystem allows opening a directory.
            if let Ok(d) = File::open(if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                dir
            }) {
                let _ = d.sync_all();
            }
        }
        Ok(())
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Deletes leftover `*.nimbus-tmp` files anywhere under `run_dir` (symlinks are not followed)
/// and returns their paths. A missing `run_dir` has none.
pub fn remove_temp_files(run_dir: &Path) -> Result<Vec<PathBuf>> {
    let mut removed = Vec::new();
    let mut stack = vec![run_dir.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let rd = match fs::read_dir(&dir) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(Error::io(&dir, e)),
        };
        let mut entries = Vec::new();
        for entry in rd {
            entries.push(entry.map_err(|e| Error::io(&dir, e))?);
        }
        entries.sort_by_key(|e| e.file_name());
        for entry in entries {
            let ft = entry.file_type().map_err(|e| Error::io(entry.path(), e))?;
            let path = entry.path();
            if ft.is_dir() {
                stack.push(path);
            } else if ft.is_file() && entry.file_name().to_string_lossy().ends_with(TMP_SUFFIX) {
                fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
                removed.push(path);
            }
        }
    }
    removed.sort();
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_without_leftovers() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.bin");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"two");
        assert_eq!(leftovers(dir.path()), 0);
    }

    #[test]
    fn failure_keeps_previous_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.bin");
        write_atomic(&p, b"good").unwrap();
        let err = write_atomic_with(&p, |_| Err(std::io::Error::other("disk full"))).unwrap_err();
        assert!(err.to_string().contains("disk full"));
        assert_eq!(fs::read(&p).unwrap(), b"good");
        assert_eq!(leftovers(dir.path()), 0);
    }

    fn leftovers(dir: &Path) -> usize {
        fs::read_dir(dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().ends_with(TMP_SUFFIX))
            .count()
    }

    #[test]
    fn temp_names_are_unique_and_carry_the_pid() {
        let p = Path::new("d/a.bin");
        let (a, b) = (tmp_path(p), tmp_path(p));
        assert_ne!(a, b);
        let name = a.file_name().unwrap().to_string_lossy().to_string();
        assert!(
            name.starts_with(&format!("a.bin.{}-", std::process::id())),
            "{name}"
        );
        assert!(name.ends_with(TMP_SUFFIX), "{name}");
    }
}
