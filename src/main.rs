//! `nimbus` command line: parse, call into the library, map errors to exit codes.
use clap::{Parser, Subcommand};
use nimbus::error::exit;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "nimbus",
    version,
    about = "Particle clouds on the GPU, written as OpenVDB/OpenEXR sequences"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check shot configs without running them; prints one line per file.
    Validate {
        /// Config files (YAML).
        #[arg(required = true)]
        configs: Vec<PathBuf>,
        /// Override a key before validation, e.g. `--set output.frames.end=10` (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
}

fn main() {
    let cli = Cli::parse();
    let code = match cli.command {
        Command::Validate { configs, set } => validate(&configs, &set),
    };
    std::process::exit(code);
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
