//! Progress reporting: an indicatif bar on a terminal, plain lines otherwise, JSON lines for farms.
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// A progress bar on a terminal, plain lines otherwise.
    Human,
    /// One JSON object per line on stderr (farm logs).
    Json,
}

pub struct Progress {
    format: LogFormat,
    bar: Option<ProgressBar>,
    start: u32,
    end: u32,
}

impl Progress {
    pub fn new(format: LogFormat, start: u32, end: u32, first: u32) -> Self {
        let total = (end - start + 1) as u64;
        let bar = (format == LogFormat::Human && std::io::stderr().is_terminal()).then(|| {
            let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
            bar.set_style(
                ProgressStyle::with_template(
                    "{prefix} [{bar:30}] {pos}/{len} frames, ETA {eta} {msg}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            bar.set_prefix("nimbus");
            bar.set_position((first - start) as u64);
            bar
        });
        Self {
            format,
            bar,
            start,
            end,
        }
    }

    /// The phase now running on frame `frame` (shown on the bar only; lines would be noise).
    pub fn phase(&self, frame: u32, phase: &str, particles: u64) {
        if let Some(bar) = &self.bar {
            bar.set_message(format!("frame {frame}: {phase}, {particles} particles"));
        }
    }

    /// A frame is fully written.
    pub fn frame_done(&self, frame: u32, particles: u64, wall_ms: f64) {
        match (&self.bar, self.format) {
            (Some(bar), _) => bar.set_position((frame - self.start + 1) as u64),
            (None, LogFormat::Json) => eprintln!(
                "{}",
                serde_json::json!({"event": "frame", "frame": frame, "of": self.end, "particles": particles, "wall_ms": wall_ms})
            ),
            (None, LogFormat::Human) => {
                eprintln!(
                    "frame {frame}/{}: {particles} particles, {wall_ms:.0} ms",
                    self.end
                )
            }
        }
    }

    /// A message that must be seen (checkpoint written, resume info, warnings).
    pub fn note(&self, event: &str, msg: &str) {
        match (&self.bar, self.format) {
            (Some(bar), _) => bar.println(msg),
            (None, LogFormat::Json) => {
                eprintln!("{}", serde_json::json!({"event": event, "message": msg}))
            }
            (None, LogFormat::Human) => eprintln!("{msg}"),
        }
    }

    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}
