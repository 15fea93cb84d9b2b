//! Dailies: the previews of a run encoded as one H.264 MP4 (`preview/<shot>.mp4`) with ffmpeg,
//! only when `output.preview.movie` asks for it. Bit-exact flags, one encoder thread and no
//! metadata, so the same previews and the same ffmpeg give the same bytes.
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Whether `ffmpeg` runs.
pub fn ffmpeg_available() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Fails, before anything is simulated, when the movie is asked for and ffmpeg is missing.
pub fn require_ffmpeg() -> Result<()> {
    if ffmpeg_available() {
        return Ok(());
    }
    Err(Error::Runtime(
        "output.preview.movie: ffmpeg is not on PATH; install it (tools/setup.sh --preview, Debian package ffmpeg) or set output.preview.movie: false".into(),
    ))
}

/// The movie `out` (`preview/<shot>.mp4`) of the PNGs `frames` (consecutive frame numbers, in
/// order, named by the ffmpeg input pattern `pattern`) at `fps`.
pub fn write_movie(
    out: &Path,
    pattern: &Path,
    frames: &[(u32, PathBuf)],
    fps: f64,
) -> Result<PathBuf> {
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
        return Err(Error::Runtime("movie: no preview frames".into()));
    };
    if last.0 - first.0 + 1 != frames.len() as u32 {
        return Err(Error::Runtime(format!(
            "movie: preview frames {}..={} have gaps",
            first.0, last.0
        )));
    }
    let tmp = crate::io::atomic::tmp_path(out);
    let result = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y", "-framerate"])
        .arg(format!("{fps}"))
        .args(["-start_number", &first.0.to_string(), "-i"])
        .arg(pattern)
        .args(["-frames:v", &frames.len().to_string()])
        // H.264 in yuv420p needs even sizes; every player reads yuv420p
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264"])
        .args(["-pix_fmt", "yuv420p", "-crf", "18", "-threads", "1"])
        .args(["-map_metadata", "-1", "-fflags", "+bitexact"])
        .args(["-flags:v", "+bitexact", "-f", "mp4"])
        .arg(&tmp)
        .output();
    let fail = |why: String| {
        let _ = std::fs::remove_file(&tmp);
        Err(Error::Runtime(format!("movie {}: {why}", out.display())))
    };
    match result {
        Err(e) => return fail(format!("cannot run ffmpeg: {e}")),
        Ok(o) if !o.status.success() => {
            let err = String::from_utf8_lossy(&o.stderr);
            return fail(format!(
                "ffmpeg failed ({}): {}",
                o.status,
                err.lines().last().unwrap_or("")
            ));
        }
        Ok(_) => {}
    }
    if let Err(e) = std::fs::rename(&tmp, out) {
        return fail(format!("cannot rename: {e}"));
    }
    Ok(out.to_path_buf())
}
