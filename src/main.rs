//! `nimbus` command line: parse, call into the library, map errors to exit codes.
use clap::{Parser, Subcommand};
use nimbus::error::{exit, Error, Result};
use nimbus::pipeline::lock::{Create, RunLock};
use nimbus::pipeline::{self, LogFormat, RunOptions, Start};
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(
    name = "nimbus",
    version,
    about = "Particle clouds on the GPU, written as OpenVDB/OpenEXR sequences",
    after_help = "Exit codes: 0 ok, 2 invalid input, 3 runtime/I-O failure, 4 no GPU adapter, 130 interrupted."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a shot and write its VDB/EXR/preview frames, manifest and stats.
    Run {
        /// Shot config (YAML).
        config: PathBuf,
        /// Run directory (default: the config's output.dir).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a key, e.g. `--set output.frames.end=10` (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Go on from the newest valid checkpoint in the run directory (output-only keys may
        /// change; simulation keys may not).
        #[arg(long)]
        resume: bool,
        /// Start over in a run directory that holds an earlier run: removes only the files
        /// that run's manifest and checkpoints list as nimbus's own (a directory holding any
        /// other file is refused).
        #[arg(long, conflicts_with = "resume")]
        force: bool,
        /// Progress output: a bar/plain lines, or JSON lines for farm logs.
        #[arg(long, value_enum, default_value = "human")]
        log_format: LogFormat,
    },
    /// Check shot configs without running them; prints one line per file.
    Validate {
        /// Config files (YAML).
        #[arg(required = true)]
        configs: Vec<PathBuf>,
        /// Override a key before validation, e.g. `--set output.frames.end=10` (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Go on with an interrupted run from its newest valid checkpoint.
    Resume {
        /// The run directory (holds manifest.json and checkpoints/).
        out_dir: PathBuf,
        /// Progress output: a bar/plain lines, or JSON lines for farm logs.
        #[arg(long, value_enum, default_value = "human")]
        log_format: LogFormat,
    },
    /// Describe a .vdb, .exr or checkpoint file.
    Inspect { file: PathBuf },
    /// (Re)render the preview images of a run from its VDB files.
    Preview {
        /// The run directory.
        out_dir: PathBuf,
        /// Camera/light overrides, e.g. `--set output.preview.sun_direction=[1,1,0]`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Re-make a run's VDB/EXR/preview files from its particle caches (export.particles),
    /// without simulating. With the run's own settings: in the run directory, byte-identical
    /// to what the run wrote; with other `--set export.*` values: in RUN_DIR/exports/NAME/.
    Export {
        /// The run directory.
        run_dir: PathBuf,
        /// Inclusive frame range A-B (default: every frame of the run).
        #[arg(long, value_name = "A-B")]
        frames: Option<String>,
        /// An export setting, e.g. `--set export.voxel_size=6.25` (repeatable; export.* only).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Name of the export directory under RUN_DIR/exports/ (default: a hash of the
        /// export settings).
        #[arg(long)]
        name: Option<String>,
    },
    /// Wedges and long simulations on a Slurm cluster (see docs/FARM.md).
    Farm {
        #[command(subcommand)]
        action: nimbus::farm::cli::FarmCommand,
    },
    /// Benchmarks behind docs/PERFORMANCE.md (prints JSON).
    Bench {
        #[command(subcommand)]
        topic: BenchTopic,
    },
}

#[derive(Subcommand)]
enum BenchTopic {
    /// PBF step timings (GPU).
    Pbf {
        #[arg(long, default_value_t = 100_000)]
        particles: usize,
        #[arg(long, default_value_t = 5)]
        steps: u32,
        /// Substeps run before timing (the box starts as a lattice; a few dozen substeps of
        /// gravity and random initial velocities disorder it as a running shot is).
        #[arg(long, default_value_t = 1)]
        warmup: u32,
    },
    /// VDB write speed and size, nimbus against OpenVDB (pyopenvdb) on the same grid.
    Vdb {
        #[arg(long, default_value_t = 4_020_000)]
        active_voxels: usize,
        /// none, zip or blosc (OpenVDB's writer is compared for blosc).
        #[arg(long, default_value = "blosc", value_parser = parse_compression)]
        compression: nimbus::config::Compression,
        #[arg(long, default_value_t = 5)]
        reps: usize,
    },
    /// Splat throughput.
    Splat {
        #[arg(long, default_value_t = 100_000)]
        particles: usize,
        #[arg(long, default_value_t = 0.5)]
        voxel: f64,
    },
    /// Preview render time on a synthetic cloud grid of DIM^3 voxels.
    Preview {
        #[arg(long, default_value_t = 640)]
        width: u32,
        #[arg(long, default_value_t = 360)]
        height: u32,
        #[arg(long, default_value_t = 256)]
        dim: u32,
        /// Worker threads (0 = all cores).
        #[arg(long, default_value_t = 0)]
        threads: usize,
    },
    /// The `export.detail` figures (mass, energy below the spacing, frame-to-frame correlation,
    /// time) on a run's particle caches (docs/RENDERING.md "Sub-particle detail").
    Detail {
        run_dir: PathBuf,
        /// Frames A-B (default: all the run has).
        #[arg(long)]
        frames: Option<String>,
        /// Voxel size (m); default: spacing / 4.
        #[arg(long)]
        voxel: Option<f64>,
        /// `export.detail.*` overrides of the run's settings.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Checkpoint size and write time.
    Checkpoint {
        #[arg(long, default_value_t = 100_000)]
        particles: usize,
    },
    /// The paper's Table 1: both paper scenarios, adaptive and not, ms per step and phase.
    /// Prints the markdown table, then the JSON.
    Table1 {
        /// Fraction of the shots' x and z extent (the height is kept).
        #[arg(long, default_value_t = 0.25)]
        scale: f64,
        /// Measured frames per run.
        #[arg(long, default_value_t = 3)]
        frames: u32,
        /// Frames simulated before measuring (extended until the adaptive run has split).
        #[arg(long, default_value_t = 40)]
        warmup: u32,
    },
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Validate { configs, set } => std::process::exit(validate(&configs, &set)),
        Command::Run {
            config,
            out,
            set,
            resume,
            force,
            log_format,
        } => run(&config, out, &set, resume, force, log_format),
        Command::Resume {
            out_dir,
            log_format,
        } => resume(&out_dir, log_format),
        Command::Inspect { file } => inspect(&file),
        Command::Preview { out_dir, set } => preview(&out_dir, &set),
        Command::Export {
            run_dir,
            frames,
            set,
            name,
        } => export(&run_dir, frames.as_deref(), set, name),
        Command::Farm { action } => nimbus::farm::cli::run(action),
        Command::Bench { topic } => bench(topic),
    };
    if let Err(e) = result {
        match e {
            // Config errors start with FILE:LINE:COL, which editors jump to.
            Error::Config(_) => eprintln!("{e}"),
            _ => eprintln!("error: {e}"),
        }
        std::process::exit(e.exit_code());
    }
}

fn validate(configs: &[PathBuf], set: &[String]) -> i32 {
    let mut code = exit::OK;
    for path in configs {
        match nimbus::config::load(path, set) {
            Ok(cfg) => println!(
                "{}: ok (shot '{}', frames {}..={}, {} particles, sim hash {})",
                path.display(),
                cfg.shot,
                cfg.output.frames.start,
                cfg.output.frames.end,
                nimbus::config::lattice_count(&cfg.domain),
                &nimbus::config::sim_hash(&cfg)[..12]
            ),
            Err(e) => {
                // Already `FILE:LINE:COL: KEY: message`, one line, editor-clickable.
                eprintln!("{e}");
                code = code.max(e.exit_code());
            }
        }
    }
    code
}

fn run(
    config: &Path,
    out: Option<PathBuf>,
    set: &[String],
    resume: bool,
    force: bool,
    log: LogFormat,
) -> Result<()> {
    let cfg = nimbus::config::load(config, set)?;
    let out_dir = out.unwrap_or_else(|| PathBuf::from(&cfg.output.dir));
    let create = if resume {
        Create::No
    } else {
        Create::IfMissing
    };
    let lock = RunLock::acquire(&out_dir, create, "run")?;
    if resume {
        refuse_changed_simulation(&cfg, &out_dir)?;
    }
    let start = if resume {
        Start::Resume
    } else {
        Start::Fresh { force }
    };
    pipeline::run(
        &cfg,
        &RunOptions {
            out_dir,
            log,
            start,
        },
        &lock,
    )
}

fn export(
    run_dir: &Path,
    frames: Option<&str>,
    sets: Vec<String>,
    name: Option<String>,
) -> Result<()> {
    use pipeline::reexport;
    let req = reexport::ExportRequest {
        frames: frames.map(reexport::parse_frames).transpose()?,
        sets,
        name,
    };
    let s = reexport::export(run_dir, &req)?;
    println!(
        "export: {} frames written, {} already as recorded, in {}",
        s.written.len(),
        s.unchanged.len(),
        s.dir.display()
    );
    Ok(())
}

fn resume(out_dir: &Path, log: LogFormat) -> Result<()> {
    let lock = RunLock::acquire(out_dir, Create::No, "resume")?;
    let cfg = recorded_config(out_dir)?;
    pipeline::run(
        &cfg,
        &RunOptions {
            out_dir: out_dir.to_path_buf(),
            log,
            start: Start::Resume,
        },
        &lock,
    )
}

/// The resolved config a run recorded in its manifest, with overrides applied (JSON is YAML).
fn config_of_run(out_dir: &Path, set: &[String]) -> Result<nimbus::config::ShotConfig> {
    let manifest = pipeline::records::Manifest::load(out_dir)?;
    let text = serde_json::to_string_pretty(&manifest.config)
        .map_err(|e| Error::Runtime(e.to_string()))?;
    let origin = out_dir.join(pipeline::records::MANIFEST);
    nimbus::config::load_str(&text, &origin.to_string_lossy(), set)
}

/// The run's config: from its manifest, or from its newest checkpoint when the manifest is lost.
fn recorded_config(out_dir: &Path) -> Result<nimbus::config::ShotConfig> {
    if out_dir.join(pipeline::records::MANIFEST).exists() {
        config_of_run(out_dir, &[])
    } else {
        config_of_checkpoints(out_dir)
    }
}

/// The config recorded in the newest valid checkpoint (a run whose manifest.json was lost).
fn config_of_checkpoints(out_dir: &Path) -> Result<nimbus::config::ShotConfig> {
    use nimbus::io::checkpoint;
    let dir = out_dir.join("checkpoints");
    let mut list = checkpoint::list_checkpoints(&dir)?;
    list.reverse();
    for (_, path) in list {
        let Some(cfg) = checkpoint::read_checkpoint(&path)
            .ok()
            .and_then(|ck| checkpoint::config_of(&ck))
        else {
            continue;
        };
        // Loaded through validation like any config; the checkpoint names it in errors.
        let text = serde_json::to_string_pretty(&cfg).map_err(|e| Error::Runtime(e.to_string()))?;
        let cfg = nimbus::config::load_str(&text, &path.to_string_lossy(), &[])?;
        eprintln!(
            "note: {} is missing; resuming with the config recorded in {}",
            out_dir.join(pipeline::records::MANIFEST).display(),
            path.display()
        );
        return Ok(cfg);
    }
    Err(Error::InvalidInput(format!(
        "{}: not a nimbus run directory: no manifest.json, and no checkpoint that records its config",
        out_dir.display()
    )))
}

/// `run --resume` with a config whose simulation keys differ from the run's is refused.
fn refuse_changed_simulation(cfg: &nimbus::config::ShotConfig, out_dir: &Path) -> Result<()> {
    let recorded = recorded_config(out_dir)?;
    let diff = nimbus::config::sim_key_diff(&recorded, cfg);
    if diff.is_empty() {
        Ok(())
    } else {
        Err(Error::InvalidInput(format!(
            "{}: cannot resume: simulation keys differ from the run's: {}",
            out_dir.display(),
            diff.join(", ")
        )))
    }
}

fn inspect(file: &Path) -> Result<()> {
    println!("{}", nimbus::io::inspect::describe(file)?);
    Ok(())
}

fn preview(out_dir: &Path, set: &[String]) -> Result<()> {
    let _lock = RunLock::acquire(out_dir, Create::No, "preview")?;
    let cfg = config_of_run(out_dir, set)?;
    let written = pipeline::rerender::rerender_previews(out_dir, &cfg)?;
    println!(
        "{written} previews written to {}",
        out_dir.join("preview").display()
    );
    Ok(())
}

fn bench(topic: BenchTopic) -> Result<()> {
    let report = match topic {
        BenchTopic::Pbf {
            particles,
            steps,
            warmup,
        } => nimbus::bench::pbf::bench_pbf(particles, steps, warmup)?,
        BenchTopic::Vdb {
            active_voxels,
            compression,
            reps,
        } => nimbus::bench::vdb::bench_vdb_write(active_voxels, compression, reps)?,
        BenchTopic::Splat { particles, voxel } => {
            nimbus::bench::splat::bench_splat(particles, voxel)?
        }
        BenchTopic::Preview {
            width,
            height,
            dim,
            threads,
        } => {
            let threads = if threads == 0 {
                std::thread::available_parallelism().map_or(1, |n| n.get())
            } else {
                threads
            };
            nimbus::bench::preview::bench_preview(width, height, dim, threads)?
        }
        BenchTopic::Detail {
            run_dir,
            frames,
            voxel,
            set,
        } => {
            let frames = frames
                .map(|f| nimbus::pipeline::reexport::parse_frames(&f))
                .transpose()?;
            nimbus::bench::detail::bench_detail(&run_dir, frames, voxel, &set)?
        }
        BenchTopic::Checkpoint { particles } => {
            nimbus::bench::checkpoint::bench_checkpoint(particles)?
        }
        BenchTopic::Table1 {
            scale,
            frames,
            warmup,
        } => {
            let report = nimbus::bench::table1::bench_table1(scale, frames, warmup)?;
            if let Some(table) = report["table"].as_str() {
                println!("{table}");
            }
            report
        }
    };
    println!(
        "{}",
        serde_json::to_string_pretty(&report).map_err(|e| Error::Runtime(e.to_string()))?
    );
    Ok(())
}

fn parse_compression(s: &str) -> std::result::Result<nimbus::config::Compression, String> {
    use nimbus::config::Compression;
    match s {
        "none" => Ok(Compression::None),
        "zip" => Ok(Compression::Zip),
        "blosc" => Ok(Compression::Blosc),
        _ => Err(format!("'{s}' is not one of none, zip, blosc")),
    }
}
