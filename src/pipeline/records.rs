//! Run records: `manifest.json` (the farm's hand-off) and `stats.jsonl` (one line per frame).
//! Both are rewritten whole and atomically after every frame, so a reader (or a resume after a
//! crash) never sees half a record.
use super::run_dir::RunDir;
use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use crate::sim::diagnostics::{AtmosphereDiagnostics, CloudDiagnostics};
use crate::sim::phase::PhaseTimes;
use crate::sim::StepDiagnostics;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One output file of a frame, path relative to the run directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileRecord {
    pub path: String,
    pub bytes: u64,
    pub sha256: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    pub frame: u32,
    pub files: Vec<FileRecord>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub tool: String,
    pub version: String,
    pub shot: String,
    /// The resolved config (after `--set` overrides and defaults).
    pub config: serde_json::Value,
    /// Hash of the whole resolved config, and of its simulation-affecting keys only.
    pub config_hash: String,
    pub sim_hash: String,
    pub adapter: String,
    pub frame_start: u32,
    pub frame_end: u32,
    pub fps: f64,
    /// Transform of every VDB grid of the shot, in scene units of the export frame (voxel
    /// centres on integer index points).
    pub voxel_size: f64,
    pub grid_origin: [f64; 3],
    /// The export frame of the VDB files: scale, up axis, velocity basis (`export::ExportSpace`);
    /// absent in manifests written before it existed (then: metres, y-up, simulated m/s).
    #[serde(default)]
    pub export: Option<crate::export::ExportSpace>,
    /// Every `physics.sources` entry: shape, bounds in metres, rates, schedule and heat map
    /// (`sim::sources::records`); left out when the shot has none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sources: Vec<crate::sim::sources::SourceRecord>,
    /// `output.preroll`: what was simulated before `frame_start` and not written; left out
    /// when the shot has no pre-roll.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preroll: Option<PrerollRecord>,
    /// The command line that resumes this run.
    pub resume_command: String,
    /// The USD layer `<shot>.usda` (`export.usd`), rewritten with every frame recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub usd: Option<FileRecord>,
    pub frames: Vec<FrameRecord>,
    /// True once every frame of the range is written.
    pub complete: bool,
}

impl Manifest {
    pub fn load(run_dir: &RunDir) -> Result<Self> {
        let path = run_dir.manifest();
        let text = std::fs::read_to_string(&path)
            .map_err(|e| Error::InvalidInput(format!("{}: {e}", path.display())))?;
        serde_json::from_str(&text).map_err(|e| {
            Error::InvalidInput(format!("{}: not a nimbus manifest: {e}", path.display()))
        })
    }

    pub fn save(&self, run_dir: &RunDir) -> Result<()> {
        let mut text =
            serde_json::to_string_pretty(self).map_err(|e| Error::Runtime(e.to_string()))?;
        text.push('\n');
        write_atomic(&run_dir.manifest(), text.as_bytes())
    }

    /// Records a frame's files, replacing an earlier record of the same frame; frames stay sorted.
    pub fn record_frame(&mut self, rec: FrameRecord) {
        self.frames.retain(|f| f.frame != rec.frame);
        let at = self.frames.partition_point(|f| f.frame < rec.frame);
        self.frames.insert(at, rec);
    }

    pub fn frame(&self, frame: u32) -> Option<&FrameRecord> {
        self.frames.iter().find(|f| f.frame == frame)
    }
}

/// The pre-roll of a run: whole frames of `frame_seconds` simulated before the first written
/// frame (`output.preroll` rounded up to whole frames).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrerollRecord {
    pub frames: u32,
    /// Simulated seconds of pre-roll: frames x frame_seconds.
    pub seconds: f64,
    /// Simulated time at the end of the first written frame (stats.jsonl `sim_time`).
    pub first_frame_time: f64,
}

impl PrerollRecord {
    pub fn of(cfg: &crate::config::ShotConfig) -> Option<Self> {
        let frames = cfg.output.preroll_frames();
        let fs = cfg.output.frame_seconds;
        (frames > 0).then_some(Self {
            frames,
            seconds: frames as f64 * fs,
            first_frame_time: (frames as f64 + 1.0) * fs,
        })
    }
}

/// What a frame measured, typed: the line of stats.jsonl it becomes ([`StatsLine`]) names each
/// figure under the key the typed source writes it with (`PhaseTimes::by_key`,
/// `StepDiagnostics::insert_into`, ...), so a key is spelled in one place.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameStats {
    pub frame: u32,
    pub sim_time: f64,
    pub particles: u64,
    /// The simulation's phases (GPU timestamps where the adapter has them).
    pub phases: PhaseTimes,
    /// The writer's phases, once the writer has written the frame.
    pub writer: WriterTimes,
    pub step: StepDiagnostics,
    pub cloud: CloudDiagnostics,
    pub atmosphere: AtmosphereDiagnostics,
}

impl FrameStats {
    /// The frame's line of stats.jsonl.
    pub fn line(&self) -> StatsLine {
        let mut phase_ms = self.phases.by_key();
        self.writer.insert_into(&mut phase_ms);
        let mut diagnostics = self.step.to_map();
        self.cloud.insert_into(&mut diagnostics);
        self.atmosphere.insert_into(&mut diagnostics);
        StatsLine {
            frame: self.frame,
            sim_time: self.sim_time,
            particles: self.particles,
            phase_ms,
            diagnostics,
        }
    }
}

/// Milliseconds the writer spent on a frame, per step (`None`: the step did not run).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WriterTimes {
    pub splat: Option<f64>,
    pub write_exr: Option<f64>,
    pub preview: Option<f64>,
    pub write_particles: Option<f64>,
    pub write_vdb: Option<f64>,
    pub write_nanovdb: Option<f64>,
}

impl WriterTimes {
    /// The steps' stats.jsonl `phase_ms` names, in the order of [`WriterTimes::values`].
    pub const KEYS: [&'static str; 6] = [
        "splat",
        "write_exr",
        "preview",
        "write_particles",
        "write_vdb",
        "write_nanovdb",
    ];

    fn values(&self) -> [Option<f64>; 6] {
        [
            self.splat,
            self.write_exr,
            self.preview,
            self.write_particles,
            self.write_vdb,
            self.write_nanovdb,
        ]
    }

    /// Adds the steps that ran under their stats.jsonl `phase_ms` names.
    pub fn insert_into(&self, out: &mut BTreeMap<String, f64>) {
        for (k, v) in Self::KEYS.iter().zip(self.values()) {
            if let Some(v) = v {
                out.insert(k.to_string(), v);
            }
        }
    }
}

/// One line of stats.jsonl as written and read: the figures by name, keys sorted. A resume
/// reads the lines of earlier frames (of this or an older nimbus) and writes them back as read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatsLine {
    pub frame: u32,
    pub sim_time: f64,
    pub particles: u64,
    /// Milliseconds per phase.
    pub phase_ms: BTreeMap<String, f64>,
    /// Physical diagnostics (density error, water, cloud mass, ...).
    pub diagnostics: BTreeMap<String, f64>,
}

/// stats.jsonl held in memory and rewritten atomically.
#[derive(Debug, Default)]
pub struct StatsLog {
    lines: Vec<StatsLine>,
}

impl StatsLog {
    /// Loads the lines of frames before `before_frame` (a resume drops what comes after).
    pub fn load_until(run_dir: &RunDir, before_frame: u32) -> Result<Self> {
        let path = run_dir.stats();
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::default()),
            Err(e) => return Err(Error::io(path, e)),
        };
        let mut lines = Vec::new();
        for (n, line) in text.lines().enumerate() {
            let s: StatsLine = serde_json::from_str(line)
                .map_err(|e| Error::InvalidInput(format!("{}:{}: {e}", path.display(), n + 1)))?;
            if s.frame < before_frame {
                lines.push(s);
            }
        }
        Ok(Self { lines })
    }

    pub fn push(&mut self, s: &FrameStats) {
        self.lines.retain(|l| l.frame != s.frame);
        self.lines.push(s.line());
    }

    pub fn save(&self, run_dir: &RunDir) -> Result<()> {
        let mut text = String::new();
        for l in &self.lines {
            text += &serde_json::to_string(l).map_err(|e| Error::Runtime(e.to_string()))?;
            text.push('\n');
        }
        write_atomic(&run_dir.stats(), text.as_bytes())
    }

    pub fn lines(&self) -> &[StatsLine] {
        &self.lines
    }
}

/// Size and SHA-256 of a file written under `run_dir`.
pub fn file_record(run_dir: &Path, path: &Path) -> Result<FileRecord> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    Ok(FileRecord {
        path: relative(run_dir, path),
        bytes: bytes.len() as u64,
        sha256: sha256_hex(&bytes),
    })
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// True when every file of the record exists with the recorded size and checksum.
pub fn frame_intact(run_dir: &Path, rec: &FrameRecord) -> bool {
    rec.files.iter().all(|f| {
        let p: PathBuf = run_dir.join(&f.path);
        std::fs::read(&p)
            .map(|b| b.len() as u64 == f.bytes && sha256_hex(&b) == f.sha256)
            .unwrap_or(false)
    })
}

fn relative(run_dir: &Path, path: &Path) -> String {
    path.strip_prefix(run_dir)
        .unwrap_or(path)
        .to_string_lossy()
        .replace('\\', "/")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_stay_sorted_and_unique() {
        let mut m = Manifest {
            tool: "nimbus".into(),
            version: "0".into(),
            shot: "s".into(),
            config: serde_json::Value::Null,
            config_hash: String::new(),
            sim_hash: String::new(),
            adapter: String::new(),
            frame_start: 1,
            frame_end: 3,
            fps: 24.0,
            voxel_size: 1.0,
            grid_origin: [0.0; 3],
            export: None,
            sources: vec![],
            preroll: None,
            resume_command: String::new(),
            usd: None,
            frames: vec![],
            complete: false,
        };
        for f in [3, 1, 2, 1] {
            m.record_frame(FrameRecord {
                frame: f,
                files: vec![],
            });
        }
        assert_eq!(
            m.frames.iter().map(|f| f.frame).collect::<Vec<_>>(),
            [1, 2, 3]
        );
    }

    #[test]
    fn stats_resume_drops_later_frames() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = StatsLog::default();
        for f in 1..=5 {
            log.push(&FrameStats {
                frame: f,
                sim_time: f as f64,
                particles: 10,
                ..Default::default()
            });
        }
        let run = RunDir::new(dir.path());
        log.save(&run).unwrap();
        let back = StatsLog::load_until(&run, 4).unwrap();
        assert_eq!(
            back.lines().iter().map(|l| l.frame).collect::<Vec<_>>(),
            [1, 2, 3]
        );
    }

    #[test]
    fn intact_detects_a_changed_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.vdb");
        std::fs::write(&p, b"abc").unwrap();
        let rec = FrameRecord {
            frame: 1,
            files: vec![file_record(dir.path(), &p).unwrap()],
        };
        assert_eq!(rec.files[0].path, "a.vdb");
        assert!(frame_intact(dir.path(), &rec));
        std::fs::write(&p, b"abd").unwrap();
        assert!(!frame_intact(dir.path(), &rec));
    }

    /// The typed record becomes the line of today's keys: phases under their stats keys
    /// (predict and solve summed as "pbf"), the writer's steps that ran, every diagnostic.
    #[test]
    fn a_frame_becomes_the_line_of_its_keys() {
        use crate::sim::Phase;
        let mut s = FrameStats {
            frame: 3,
            sim_time: 0.5,
            particles: 7,
            ..Default::default()
        };
        s.phases.add(Phase::Predict, 1.0);
        s.phases.add(Phase::Solve, 2.0);
        s.writer.splat = Some(4.0);
        s.step.cfl_max = 0.25;
        s.atmosphere.clamped_particles = 2;
        let line = s.line();
        let keys: Vec<&str> = line.phase_ms.keys().map(String::as_str).collect();
        assert_eq!(keys, ["pbf", "splat"]);
        assert_eq!(line.phase_ms["pbf"], 3.0);
        assert_eq!(line.diagnostics["cfl_max"], 0.25);
        assert_eq!(line.diagnostics["clamped_particles"], 2.0);
        assert!(line.diagnostics.contains_key("total_water"));
        assert!(!line.diagnostics.contains_key("splits"));
        let text = serde_json::to_string(&line).unwrap();
        assert!(text.starts_with(r#"{"frame":3,"sim_time":0.5,"particles":7,"phase_ms":{"pbf":3.0,"splat":4.0},"diagnostics":{"cfl_max":0.25,"clamped_particles":2.0,"#), "{text}");
    }

    /// A resume writes the lines it read back as they were, keys it does not know included.
    #[test]
    fn read_lines_are_written_back_as_read() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunDir::new(dir.path());
        let text = "{\"frame\":1,\"sim_time\":0.25,\"particles\":5,\"phase_ms\":{\"grid\":1.5},\"diagnostics\":{\"a_retired_key\":1.0,\"cfl_max\":0.5}}\n";
        std::fs::write(run.stats(), text).unwrap();
        StatsLog::load_until(&run, 2).unwrap().save(&run).unwrap();
        assert_eq!(std::fs::read_to_string(run.stats()).unwrap(), text);
    }

    /// A resumed run writes the earlier frames' stats lines again from what it read: every f64
    /// must come back to the same bits (both values came back one ulp off before
    /// serde_json's float_roundtrip).
    #[test]
    fn stats_values_read_back_to_the_same_bits() {
        for v in [0.018552541732788086_f64, 0.23666460213703086] {
            let back: f64 = serde_json::from_str(&serde_json::to_string(&v).unwrap()).unwrap();
            assert_eq!(back.to_bits(), v.to_bits(), "{v}");
        }
    }
}
