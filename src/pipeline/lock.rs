//! The run-directory lock: `run`, `resume` and `preview` hold an exclusive `flock` on
//! `OUT/.lock` for their whole lives, so two processes never write one run directory.
//!
//! The lock file records the holder (`pid`, `host`, command) while it is held and is emptied on
//! a clean exit; the kernel drops the lock itself when a process dies, however it dies. A lock
//! that could be taken but still names another holder was left by a process that ended without
//! cleaning up (kill -9, power loss) or sits on a file system whose locks do not reach other
//! hosts (some network file systems): it is reported, never silently broken.
//! - same host, that pid no longer runs nimbus: a note, and the lock is taken over;
//! - same host, that pid still runs nimbus: refused (the file system did not enforce the lock);
//! - another host: refused, since this host cannot tell whether it still runs.
use super::run_dir::RunDir;
use crate::error::{Error, Result};
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Whether the run directory may be created.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Create {
    /// `run`: create the directory (and its parents) if missing.
    IfMissing,
    /// `resume`, `preview`: the directory must exist.
    No,
}

/// Held lock on a run directory; released (and the lock file emptied) on drop.
#[derive(Debug)]
pub struct RunLock {
    dir: PathBuf,
    file: File,
}

/// Who a lock file says holds it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    pub pid: Option<u32>,
    pub host: String,
}

/// A shared hold on a run directory's lock (`RunLock::acquire_shared`), released on drop.
pub struct SharedRunLock {
    _file: File,
}

impl RunLock {
    /// Takes the lock of `dir` for `command` (`run`, `resume`, `preview`), or fails with exit 2:
    /// "run directory DIR in use by pid N (host H)". `dir` pointing at a file, or missing when
    /// `create` is `No`, is invalid input too.
    pub fn acquire(dir: &Path, create: Create, command: &str) -> Result<Self> {
        match std::fs::metadata(dir) {
            Ok(m) if m.is_dir() => {}
            Ok(_) => {
                return Err(Error::InvalidInput(format!(
                    "{}: is a file, not a run directory",
                    dir.display()
                )))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound && create == Create::IfMissing => {
                std::fs::create_dir_all(dir).map_err(|e| {
                    Error::InvalidInput(format!(
                        "{}: cannot create the run directory: {e}",
                        dir.display()
                    ))
                })?;
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(Error::InvalidInput(format!(
                    "{}: no such run directory",
                    dir.display()
                )))
            }
            Err(e) => {
                return Err(Error::InvalidInput(format!("{}: {e}", dir.display())));
            }
        }
        let (path, mut file) = open_lock_file(dir)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let holder = read_holder_of_locked(&mut file);
                return Err(in_use(dir, &holder, ""));
            }
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(Error::InvalidInput(format!(
                    "{}: cannot lock the run directory: {e}",
                    path.display()
                )))
            }
        }
        // Locked. A holder still recorded did not end cleanly, or the lock is not enforced.
        let previous = read_holder(&mut file);
        let me = Holder {
            pid: Some(std::process::id()),
            host: host_name(),
        };
        if let Some(pid) = previous.pid {
            if previous.host != me.host {
                return Err(in_use(
                    dir,
                    &previous,
                    &format!(
                        " (recorded in {}; this host cannot check whether it still runs: if no nimbus \
                         runs there on this directory, delete the lock file)",
                        path.display()
                    ),
                ));
            }
            if pid != std::process::id() && runs_nimbus(pid) {
                return Err(in_use(
                    dir,
                    &previous,
                    " (the file system did not enforce the lock)",
                ));
            }
            eprintln!(
                "note: {}: taking over the stale lock of pid {pid} (host {}), which has ended",
                path.display(),
                previous.host
            );
        }
        let text = format!(
            "pid {}\nhost {}\ncommand {command}\n",
            std::process::id(),
            me.host
        );
        let written = (|| -> std::io::Result<()> {
            file.set_len(0)?;
            file.seek(SeekFrom::Start(0))?;
            file.write_all(text.as_bytes())?;
            file.sync_all()
        })();
        written.map_err(|e| Error::io(&path, e))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            file,
        })
    }

    /// A shared lock of `dir` for `nimbus export`: any number of exports (farm jobs on other
    /// frame ranges) hold it together, while `run`, `resume` and `preview`, which take the lock
    /// exclusively, are refused (and refuse an export) as "in use". Records no holder, as
    /// several may hold it.
    pub fn acquire_shared(dir: &Path) -> Result<SharedRunLock> {
        if !dir.is_dir() {
            return Err(Error::InvalidInput(format!(
                "{}: no such run directory",
                dir.display()
            )));
        }
        let (path, mut file) = open_lock_file(dir)?;
        match file.try_lock_shared() {
            Ok(()) => Ok(SharedRunLock { _file: file }),
            Err(std::fs::TryLockError::WouldBlock) => {
                let holder = read_holder_of_locked(&mut file);
                Err(in_use(dir, &holder, ""))
            }
            Err(std::fs::TryLockError::Error(e)) => Err(Error::InvalidInput(format!(
                "{}: cannot lock the run directory: {e}",
                path.display()
            ))),
        }
    }

    /// The locked run directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for RunLock {
    fn drop(&mut self) {
        // Empty while still locked: an empty lock file names no holder. Closing unlocks.
        let _ = self.file.set_len(0);
        let _ = self.file.sync_all();
    }
}

fn in_use(dir: &Path, h: &Holder, extra: &str) -> Error {
    let Some(pid) = h.pid else {
        // Shared holders (`nimbus export`) record nothing.
        return Error::InvalidInput(format!(
            "run directory {} in use (locked without a recorded holder: a `nimbus export` of it, or a process that is just starting){extra}",
            dir.display()
        ));
    };
    Error::InvalidInput(format!(
        "run directory {} in use by pid {pid} (host {}){extra}",
        dir.display(),
        h.host
    ))
}

/// Parses `pid N` / `host H` lines; an empty or foreign file names no pid.
pub fn parse_holder(text: &str) -> Holder {
    let mut h = Holder {
        pid: None,
        host: "unknown".into(),
    };
    for line in text.lines() {
        if let Some(p) = line.strip_prefix("pid ") {
            h.pid = p.trim().parse().ok();
        } else if let Some(host) = line.strip_prefix("host ") {
            h.host = host.trim().to_string();
        }
    }
    h
}

/// Opens (creating) `dir`'s lock file for reading the holder and locking.
/// Read only (no lock taken, nothing written): `dir` in use by a nimbus process on this host, as
/// its lock file records, is refused as [`RunLock::acquire`] would refuse it. A holder on
/// another host, or none, passes: the lock itself decides then.
pub fn check_not_in_use(dir: &Path) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(RunDir::new(dir).lock_file()) else {
        return Ok(());
    };
    let holder = parse_holder(&text);
    match holder.pid {
        Some(pid)
            if holder.host == host_name() && pid != std::process::id() && runs_nimbus(pid) =>
        {
            Err(in_use(dir, &holder, ""))
        }
        _ => Ok(()),
    }
}

fn open_lock_file(dir: &Path) -> Result<(PathBuf, File)> {
    let path = RunDir::new(dir).lock_file();
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| {
            Error::InvalidInput(format!(
                "{}: cannot open the lock file: {e}",
                path.display()
            ))
        })?;
    Ok((path, file))
}

/// The holder of a lock another process holds. A process writes its holder just after it
/// takes the lock, so an empty file is read again for up to half a second before it is
/// reported as "no recorded holder" (two resumes started together: the loser names the winner).
fn read_holder_of_locked(file: &mut File) -> Holder {
    for _ in 0..25 {
        let h = read_holder(file);
        if h.pid.is_some() {
            return h;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    read_holder(file)
}

fn read_holder(file: &mut File) -> Holder {
    let mut text = String::new();
    let _ = file.seek(SeekFrom::Start(0));
    let _ = file.take(4096).read_to_string(&mut text);
    parse_holder(&text)
}

/// This machine's host name (`/proc/sys/kernel/hostname`, `$HOSTNAME`, or "unknown").
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok().filter(|s| !s.is_empty()))
        .unwrap_or_else(|| "unknown".into())
}

/// Whether process `pid` of this host is a running nimbus (Linux `/proc`; elsewhere: assumed).
fn runs_nimbus(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    std::fs::read_to_string(format!("/proc/{pid}/comm"))
        .map(|c| c.trim().starts_with("nimbus"))
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_is_refused_with_the_holder() {
        let dir = tempfile::tempdir().unwrap();
        let a = RunLock::acquire(dir.path(), Create::No, "run").unwrap();
        let err = RunLock::acquire(dir.path(), Create::No, "resume").unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains(&format!("in use by pid {}", std::process::id())),
            "{msg}"
        );
        assert_eq!(err.exit_code(), 2);
        drop(a);
        let text = std::fs::read_to_string(RunDir::new(dir.path()).lock_file()).unwrap();
        assert!(text.is_empty(), "{text:?}");
        RunLock::acquire(dir.path(), Create::No, "resume").unwrap();
    }

    #[test]
    fn shared_holds_exclude_only_exclusive_ones() {
        let dir = tempfile::tempdir().unwrap();
        let a = RunLock::acquire_shared(dir.path()).unwrap();
        let b = RunLock::acquire_shared(dir.path()).unwrap();
        let err = RunLock::acquire(dir.path(), Create::No, "run").unwrap_err();
        assert!(err.to_string().contains("nimbus export"), "{err}");
        assert_eq!(err.exit_code(), 2);
        drop((a, b));
        let run = RunLock::acquire(dir.path(), Create::No, "run").unwrap();
        let err = RunLock::acquire_shared(dir.path()).err().unwrap();
        assert!(
            err.to_string()
                .contains(&format!("in use by pid {}", std::process::id())),
            "{err}"
        );
        drop(run);
        RunLock::acquire_shared(dir.path()).unwrap();
    }

    #[test]
    fn another_hosts_lock_is_reported_not_broken() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            RunDir::new(dir.path()).lock_file(),
            "pid 42\nhost elsewhere-xyz\n",
        )
        .unwrap();
        let msg = RunLock::acquire(dir.path(), Create::No, "run")
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("in use by pid 42 (host elsewhere-xyz)"),
            "{msg}"
        );
    }

    #[test]
    fn a_file_or_a_missing_dir_is_invalid_input() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("f");
        std::fs::write(&f, "x").unwrap();
        let e = RunLock::acquire(&f, Create::IfMissing, "run").unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        let e = RunLock::acquire(&dir.path().join("nope"), Create::No, "resume").unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
    }
}
