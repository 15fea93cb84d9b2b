//! Names in messages about a run directory: the command that resumes it, frame ranges.
use std::path::Path;

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
    fn resume_command_quotes_odd_paths() {
        assert_eq!(resume_command(Path::new("out/a")), "nimbus resume out/a");
        assert_eq!(
            resume_command(Path::new("my out")),
            "nimbus resume 'my out'"
        );
    }
}
