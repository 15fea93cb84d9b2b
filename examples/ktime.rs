use nimbus::sim::{Simulation, Stage};
use std::sync::Arc;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let n: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(100_000);
    let warm: u32 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let cfg = nimbus::bench::pbf::bench_config(n).unwrap();
    let ctx = Arc::new(nimbus::gpu::Context::new(&Default::default()).unwrap());
    let mut sim = Simulation::new(ctx, &cfg).unwrap();
    for _ in 0..warm { sim.step_frame().unwrap(); }
    sim.run_stage(Stage::Predict).unwrap();
    sim.run_stage(Stage::Grid).unwrap();
    for st in [Stage::Lambda, Stage::Delta, Stage::Lambda, Stage::Delta, Stage::UpdateVelocity, Stage::Vorticity, Stage::ViscosityConfine] {
        let t = std::time::Instant::now();
        let reps = 5;
        for _ in 0..reps { sim.run_stage(st).unwrap(); }
        println!("{st:?}: {:.1} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    }
}
