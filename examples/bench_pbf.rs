//! `cargo run --example bench_pbf -- PARTICLES STEPS [WARMUP]`: prints
//! `nimbus::bench::pbf::bench_pbf` as JSON.
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let n = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let steps = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let warmup = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    match nimbus::bench::pbf::bench_pbf(&nimbus::bench::pbf::PbfBench::new(n, steps, warmup)) {
        Ok(v) => println!("{}", serde_json::to_string_pretty(&v).unwrap()),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(e.exit_code());
        }
    }
}
