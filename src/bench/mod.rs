//! Measurement commands: figures for docs/PERFORMANCE.md, never timed tests.
pub mod checkpoint;
pub mod detail;
pub mod nanovdb;
pub mod pbf;
pub mod preview;
pub mod splat;
pub mod step;
pub mod surface;
pub mod table1;
pub mod vdb;

/// CPU seconds (user + system) this process has used so far, from `/proc/self/stat` (Linux,
/// USER_HZ = 100); `None` elsewhere. On a shared machine, figures per CPU second are steadier
/// than wall-clock ones.
pub fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}
