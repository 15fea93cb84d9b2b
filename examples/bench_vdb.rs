//! VDB write benchmark until the CLI exposes it as `nimbus bench vdb`:
//! `cargo run --release --example bench_vdb -- [ACTIVE_VOXELS] [none|zip|blosc] [REPS]`.
use nimbus::config::Compression;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n = args
        .get(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(4_020_000);
    let c = match args.get(2).map(String::as_str) {
        Some("none") => Compression::None,
        Some("zip") => Compression::Zip,
        _ => Compression::Blosc,
    };
    let reps = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(5);
    match nimbus::bench::vdb::bench_vdb_write(n, c, reps) {
        Ok(v) => println!("{}", serde_json::to_string_pretty(&v).unwrap()),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(e.exit_code());
        }
    }
}
