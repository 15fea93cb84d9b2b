//! `output.preview.movie`: the previews as an H.264 MP4 made by ffmpeg (read back with ffprobe),
//! the same bytes from the same previews; a missing ffmpeg stops a run that asked for the movie
//! before it simulates, and never matters to one that did not. Without ffmpeg the encoding test
//! is skipped with a note, and fails under `CI=true` (`.ci/run` installs it).
mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;

fn fresh(name: &str) -> PathBuf {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&out);
    out
}

fn have_ffmpeg() -> bool {
    let ok = ["ffmpeg", "ffprobe"].iter().all(|t| {
        Command::new(t)
            .arg("-version")
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if !ok && std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but ffmpeg/ffprobe are not on PATH (tools/setup.sh --preview)");
    }
    ok
}

const MOVIE: [&str; 2] = ["--set", "output.preview.movie=true"];

#[test]
fn previews_become_a_deterministic_h264_movie() {
    if !have_ffmpeg() {
        eprintln!("note: ffmpeg not on PATH; movie test skipped");
        return;
    }
    let a = fresh("movie_a");
    let o = run_tiny(&a, &MOVIE);
    assert!(o.status.success(), "{}", text(&o));
    let mp4 = a.join("preview/tiny.mp4");
    let probe = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-count_frames"])
        .args([
            "-show_entries",
            "stream=codec_name,width,height,nb_read_frames,r_frame_rate",
        ])
        .args(["-of", "json"])
        .arg(&mp4)
        .output()
        .unwrap();
    assert!(
        probe.status.success(),
        "{}",
        String::from_utf8_lossy(&probe.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&probe.stdout).unwrap();
    let s = &j["streams"][0];
    assert_eq!(s["codec_name"], "h264", "{j}");
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64()),
        (Some(96), Some(54)),
        "{j}"
    );
    assert_eq!(s["nb_read_frames"], "8", "{j}");
    assert_eq!(s["r_frame_rate"], "24/1", "{j}");

    let b = fresh("movie_b");
    let o = run_tiny(&b, &MOVIE);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(
        std::fs::read(&mp4).unwrap(),
        std::fs::read(b.join("preview/tiny.mp4")).unwrap(),
        "same previews, same movie"
    );
    // the movie is the run's own file: a forced fresh run over it is not refused
    let o = run_tiny(&a, &["--set", "output.frames.end=1", "--force"]);
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn ffmpeg_is_needed_only_when_the_movie_is_asked_for() {
    let empty = fresh("movie_no_path");
    std::fs::create_dir_all(&empty).unwrap();
    let out = fresh("movie_no_ffmpeg");
    let o = nimbus()
        .env("PATH", &empty)
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&out)
        .args(MOVIE)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("ffmpeg") && err.contains("output.preview.movie"),
        "{err}"
    );
    assert!(
        !out.join("vdb/tiny.0001.vdb").exists(),
        "nothing is simulated"
    );

    let out = fresh("movie_not_asked");
    let o = nimbus()
        .env("PATH", &empty)
        .arg("run")
        .arg(sample("tiny.yaml"))
        .arg("--out")
        .arg(&out)
        .args(["--set", "output.frames.end=2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));

    // the movie is made of the previews
    let o = nimbus()
        .arg("validate")
        .arg(sample("tiny.yaml"))
        .args(MOVIE)
        .args(["--set", "output.preview.enabled=false"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("output.preview.movie"));
}
