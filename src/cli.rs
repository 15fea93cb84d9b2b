//! The `nimbus` command line: every command, flag and help text (clap derive; the farm
//! subcommands are `nimbus::farm::cli`'s), and its usage errors.
use clap::error::{ContextKind, ContextValue, ErrorKind};
use clap::{Parser, Subcommand};
use nimbus::config::Compression;
use nimbus::pipeline::LogFormat;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "nimbus",
    version,
    about = "Particle clouds on the GPU, written as OpenVDB/OpenEXR sequences",
    after_help = "Exit codes: 0 ok, 2 invalid input, 3 runtime/I-O failure, 4 no GPU adapter, 130 interrupted."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
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
        /// Also open each config's GPU adapter and check that it holds the shot (largest
        /// storage binding, largest buffer, workgroups per dispatch, device memory): a shot over
        /// a limit exits 4 naming the limit and the largest particle count that fits.
        #[arg(long)]
        gpu: bool,
    },
    /// Go on with an interrupted run from its newest valid checkpoint.
    Resume {
        /// The run directory (holds manifest.json and checkpoints/).
        out_dir: PathBuf,
        /// Progress output: a bar/plain lines, or JSON lines for farm logs.
        #[arg(long, value_enum, default_value = "human")]
        log_format: LogFormat,
    },
    /// Describe a .vdb, .nvdb, .exr or checkpoint file.
    Inspect { file: PathBuf },
    /// (Re)render the preview images of a run from its VDB files, or a debug view of it.
    Preview {
        /// The run directory.
        out_dir: PathBuf,
        /// volume: the run's previews (preview/); sources: with the heat sources drawn in;
        /// target: with the control target as a ghost; particles: the particles coloured by
        /// adaptive level. The debug views write to preview/VIEW/.
        #[arg(long, value_enum, default_value = "volume")]
        view: nimbus::pipeline::rerender::View,
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
pub enum BenchTopic {
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
        /// periodic: the box filled, x/z periodic; block: a block of liquid at rest in a closed
        /// box, SPlisHSPlasH's scene (tools/bench_pbf_vs_splishsplash.py).
        #[arg(long, value_enum, default_value = "periodic")]
        scene: nimbus::bench::pbf::PbfScene,
        /// Particle spacing d in metres (default: periodic 1, block 0.05).
        #[arg(long)]
        spacing: Option<f64>,
        /// Kernel radius over spacing, h0 / d.
        #[arg(long, default_value_t = 2.0)]
        kernel_ratio: f64,
        /// Density iterations per substep.
        #[arg(long, default_value_t = 4)]
        iterations: u32,
        /// Fixed substep in seconds (default: periodic 0.02, block 0.002).
        #[arg(long)]
        dt: Option<f64>,
    },
    /// VDB write speed and size, nimbus against OpenVDB (pyopenvdb) on the same grid.
    Vdb {
        #[arg(long, default_value_t = 4_020_000)]
        active_voxels: usize,
        /// none, zip or blosc (OpenVDB's writer is compared for blosc).
        #[arg(long, value_enum, default_value = "blosc", hide_possible_values = true)]
        compression: Compression,
        #[arg(long, default_value_t = 5)]
        reps: usize,
    },
    /// NanoVDB write speed and file sizes, nimbus against nanovdb_convert on the same grids.
    Nanovdb {
        /// The grids of this VDB file (e.g. quickstart's last frame); default: a synthetic
        /// cloud of --active-voxels voxels.
        #[arg(long)]
        vdb: Option<PathBuf>,
        #[arg(long, default_value_t = 30_000_000)]
        active_voxels: usize,
        #[arg(long, default_value_t = 5)]
        reps: usize,
        /// `export.nanovdb.tolerance` for the FpN size.
        #[arg(long, default_value_t = 0.001)]
        tolerance: f64,
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
    /// The `export.detail` figures (mass, the surface: change inside, energy below the spacing in
    /// the shell, boundary thickness; frame-to-frame correlation, time) on a run's particle
    /// caches (docs/RENDERING.md "Detail at the surface").
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
        /// Only the mass and the surface figures (inside change, shell energy, boundary
        /// thickness): no frame-to-frame correlation, no timing.
        #[arg(long)]
        surface: bool,
        /// Density of the boundary the surface figures measure from, in the density grid's
        /// units (the undetailed grid's iso-surface).
        #[arg(long, default_value_t = 0.1)]
        boundary: f64,
    },
    /// Checkpoint size and write time.
    Checkpoint {
        #[arg(long, default_value_t = 100_000)]
        particles: usize,
    },
    /// The full adaptive step (PBF, smoothing, cloud physics, split, merge) of paper example 1
    /// widened in x and z to about PARTICLES particles: ms per substep and phase, particle
    /// steps per second, device bytes (JSON).
    Step {
        #[arg(long, default_value_t = 1_000_000)]
        particles: usize,
        /// Measured frames.
        #[arg(long, default_value_t = 3)]
        frames: u32,
        /// Frames simulated before measuring (extended until particles have split).
        #[arg(long, default_value_t = 40)]
        warmup: u32,
        /// Stop warming up at 80% of this many seconds and measure what there is (a bench
        /// with a time limit, as tools/gpu_machine.sh runs it).
        #[arg(long)]
        max_seconds: Option<f64>,
    },
    /// The paper's Table 1: both paper scenarios, adaptive and not, ms per step and phase.
    /// Prints the markdown table, then the JSON.
    Table1 {
        /// Fraction of the shots' x and z extent (the height is kept). 1: the scenes as they
        /// are, what the paper's Table 1 measures (about 14 minutes on 2 CPU cores). Smaller
        /// values give a quicker run of a reduced scene, where the fixed cost of split and
        /// merge's dispatches weighs more.
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
        /// Measured frames per run.
        #[arg(long, default_value_t = 3)]
        frames: u32,
        /// Frames simulated before measuring (extended until the adaptive run has split).
        #[arg(long, default_value_t = 40)]
        warmup: u32,
    },
}

/// Parses the command line. A usage error exits 2 (clap's code); a value outside a flag's
/// choices is one line, `error: --flag "value": expected a or b`, like every input error.
pub fn parse() -> Cli {
    Cli::try_parse().unwrap_or_else(|e| {
        if let Some(line) = invalid_choice(&e) {
            eprintln!("error: {line}");
            std::process::exit(nimbus::error::exit::INVALID_INPUT);
        }
        e.exit()
    })
}

/// The one-line message of an invalid value of a flag with fixed choices.
fn invalid_choice(e: &clap::Error) -> Option<String> {
    if e.kind() != ErrorKind::InvalidValue {
        return None;
    }
    let text = |kind| match e.get(kind) {
        Some(ContextValue::String(s)) => Some(s.as_str()),
        _ => None,
    };
    // The argument reads `--flag <VALUE>`; the message names the flag only.
    let flag = text(ContextKind::InvalidArg)?.split(' ').next()?;
    let value = text(ContextKind::InvalidValue)?;
    let Some(ContextValue::Strings(choices)) = e.get(ContextKind::ValidValue) else {
        return None;
    };
    let (last, rest) = choices.split_last()?;
    let expected = if rest.is_empty() {
        last.clone()
    } else {
        format!("{} or {last}", rest.join(", "))
    };
    Some(if value.is_empty() {
        format!("{flag}: a value is required: {expected}")
    } else {
        format!("{flag} {value:?}: expected {expected}")
    })
}
