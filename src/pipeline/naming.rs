//! Names of the files of a run directory.
use std::path::{Path, PathBuf};

pub const DIRS: [&str; 4] = ["vdb", "exr", "preview", "checkpoints"];

/// `<run>/<kind>/<shot>.<frame, zero-padded>.<ext>`
pub fn frame_file(
    run_dir: &Path,
    kind: &str,
    shot: &str,
    frame: u32,
    padding: u32,
    ext: &str,
) -> PathBuf {
    run_dir.join(kind).join(format!(
        "{shot}.{frame:0width$}.{ext}",
        width = padding as usize
    ))
}

/// The shell command that resumes the run in `run_dir`.
pub fn resume_command(run_dir: &Path) -> String {
    let d = run_dir.to_string_lossy();
    if d.chars()
        .all(|c| c.is_ascii_alphanumeric() || "/._-+:".contains(c))
    {
        format!("nimbus resume {d}")
    } else {
        format!("nimbus resume '{}'", d.replace('\'', "'\\''"))
    }
}

/// Frames as sorted ranges for a message: `1-35, 37-47`.
pub(crate) fn frame_ranges(frames: &[u32]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < frames.len() {
        let mut j = i;
        while j + 1 < frames.len() && frames[j + 1] == frames[j] + 1 {
            j += 1;
        }
        out.push(if i == j {
            frames[i].to_string()
        } else {
            format!("{}-{}", frames[i], frames[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_padded() {
        let p = frame_file(Path::new("out"), "vdb", "shot", 7, 4, "vdb");
        assert_eq!(p, Path::new("out/vdb/shot.0007.vdb"));
    }

    #[test]
    fn resume_command_quotes_odd_paths() {
        assert_eq!(resume_command(Path::new("out/a")), "nimbus resume out/a");
        assert_eq!(
            resume_command(Path::new("my out")),
            "nimbus resume 'my out'"
        );
    }
}
