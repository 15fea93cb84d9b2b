//! `nimbus` command line: parse, call into the library, map errors to exit codes.
mod cli;

use cli::{BenchTopic, Command};
use nimbus::error::{exit, Error, Result};
use nimbus::pipeline::{self, reexport};
use std::path::PathBuf;
use std::sync::Arc;

fn main() {
    // env_logger under the GPU validation hook (NIMBUS_GPU_VALIDATION: a validation error ends
    // the process; nimbus::gpu::validation)
    let logger =
        env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).build();
    let filter = logger.filter();
    nimbus::gpu::validation::Logger::install(Box::new(logger), filter);
    let result = match cli::parse().command {
        Command::Validate { configs, set, gpu } => {
            std::process::exit(validate(&configs, &set, gpu))
        }
        Command::Run {
            config,
            out,
            set,
            resume,
            force,
            log_format,
        } => nimbus::shot::load(&config, &set).and_then(|shot| {
            let out_dir = out.unwrap_or_else(|| PathBuf::from(&shot.config().output.dir));
            if resume {
                pipeline::resume::resume_with(&shot, &out_dir, log_format)
            } else {
                pipeline::run_fresh(&shot, &out_dir, log_format, force)
            }
        }),
        Command::Resume {
            out_dir,
            log_format,
        } => pipeline::resume::resume(&out_dir, log_format),
        Command::Inspect { file } => {
            nimbus::io::inspect::describe(&file).map(|text| nimbus::outln!("{text}"))
        }
        Command::Preview { out_dir, view, set } => {
            pipeline::rerender::rerender_run(&out_dir, &set, view).map(|(written, dir)| {
                nimbus::outln!("{written} previews written to {}", dir.display())
            })
        }
        Command::Export {
            run_dir,
            frames,
            set,
            name,
        } => export(run_dir, frames, set, name),
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

fn validate(configs: &[PathBuf], set: &[String], gpu: bool) -> i32 {
    let mut code = exit::OK;
    // one device per distinct `gpu` section (opening one takes a while)
    let mut devices: Vec<(nimbus::config::GpuConfig, Arc<nimbus::gpu::Context>)> = Vec::new();
    for path in configs {
        let shot = match nimbus::shot::load(path, set) {
            Ok(shot) => shot,
            Err(e) => {
                // Already `FILE:LINE:COL: KEY: message`, one line, editor-clickable.
                eprintln!("{e}");
                code = code.max(e.exit_code());
                continue;
            }
        };
        let cfg = shot.config();
        let fit = if gpu {
            match device_fit(&shot, &mut devices) {
                Ok(fit) => fit,
                Err(e) => {
                    eprintln!("{}: {e}", path.display());
                    code = code.max(e.exit_code());
                    continue;
                }
            }
        } else {
            String::new()
        };
        nimbus::outln!(
            "{}: ok (shot '{}', frames {}..={}, {} particles, sim hash {}{fit})",
            path.display(),
            cfg.shot,
            cfg.output.frames.start,
            cfg.output.frames.end,
            nimbus::config::lattice_count(&cfg.domain),
            &nimbus::config::sim_hash(cfg)[..12]
        );
    }
    code
}

/// `validate --gpu`: whether the adapter of `cfg.gpu` holds the shot; `devices` keeps the
/// adapters opened so far.
fn device_fit(
    shot: &nimbus::shot::Shot,
    devices: &mut Vec<(nimbus::config::GpuConfig, Arc<nimbus::gpu::Context>)>,
) -> Result<String> {
    let cfg = shot.config();
    let ctx = match devices.iter().find(|(g, _)| *g == cfg.gpu) {
        Some((_, ctx)) => ctx.clone(),
        None => {
            let ctx = Arc::new(nimbus::gpu::Context::new(&cfg.gpu)?);
            devices.push((cfg.gpu.clone(), ctx.clone()));
            ctx
        }
    };
    let (_, largest) = nimbus::sim::footprint::check_config(&ctx, shot)?;
    Ok(format!(
        "; adapter {} holds up to {largest} particles of this shot",
        ctx.adapter_name()
    ))
}

fn export(
    run_dir: PathBuf,
    frames: Option<String>,
    sets: Vec<String>,
    name: Option<String>,
) -> Result<()> {
    let req = reexport::ExportRequest {
        frames: frames.as_deref().map(reexport::parse_frames).transpose()?,
        sets,
        name,
    };
    let s = reexport::export(&run_dir, &req)?;
    nimbus::outln!(
        "export: {} frames written, {} already as recorded, in {}",
        s.written.len(),
        s.unchanged.len(),
        s.dir.display()
    );
    Ok(())
}

fn bench(topic: BenchTopic) -> Result<()> {
    use nimbus::bench;
    let report = match topic {
        BenchTopic::Pbf {
            particles,
            steps,
            warmup,
            scene,
            spacing,
            kernel_ratio,
            iterations,
            dt,
        } => bench::pbf::bench_pbf(&bench::pbf::PbfBench {
            scene,
            spacing,
            kernel_ratio,
            iterations,
            dt,
            ..bench::pbf::PbfBench::new(particles, steps, warmup)
        })?,
        BenchTopic::Vdb {
            active_voxels,
            compression,
            reps,
        } => bench::vdb::bench_vdb_write(active_voxels, compression, reps)?,
        BenchTopic::Nanovdb {
            vdb,
            active_voxels,
            reps,
            tolerance,
        } => {
            let source = match vdb {
                Some(p) => bench::nanovdb::Source::File(p),
                None => bench::nanovdb::Source::Cloud(active_voxels),
            };
            bench::nanovdb::bench_nanovdb_write(&source, reps, tolerance)?
        }
        BenchTopic::Splat { particles, voxel } => bench::splat::bench_splat(particles, voxel)?,
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
            bench::preview::bench_preview(width, height, dim, threads)?
        }
        BenchTopic::Detail {
            run_dir,
            frames,
            voxel,
            set,
            surface,
            boundary,
        } => {
            let frames = frames.map(|f| reexport::parse_frames(&f)).transpose()?;
            let opts = bench::detail::DetailBench {
                frames,
                voxel,
                surface_only: surface,
                boundary,
            };
            bench::detail::bench_detail(&run_dir, &opts, &set)?
        }
        BenchTopic::Checkpoint { particles } => bench::checkpoint::bench_checkpoint(particles)?,
        BenchTopic::Step {
            particles,
            frames,
            warmup,
            max_seconds,
        } => bench::step::bench_step(particles, frames, warmup, max_seconds)?,
        BenchTopic::Table1 {
            scale,
            frames,
            warmup,
        } => {
            let report = bench::table1::bench_table1(scale, frames, warmup)?;
            if let Some(table) = report["table"].as_str() {
                nimbus::outln!("{table}");
            }
            report
        }
    };
    nimbus::outln!(
        "{}",
        serde_json::to_string_pretty(&report).map_err(|e| Error::Runtime(e.to_string()))?
    );
    Ok(())
}
