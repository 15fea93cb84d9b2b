//! Fault injection for the crash tests: `NIMBUS_FAULT=rename:PATTERN:N` aborts the process (as
//! a SIGKILL would) just before the N-th atomic rename of a file whose path contains PATTERN,
//! i.e. with the temporary file fully written; `NIMBUS_FAULT=frame:N` aborts in the middle of
//! simulating frame N; `NIMBUS_FAULT=nan:N` makes the temperature of particle 0 NaN in the state
//! read back after frame N (for the divergence watchdog); `NIMBUS_FAULT=slow:MS` sleeps MS
//! milliseconds in every frame (a run that stays alive while a test starts other processes on
//! its directory; the output is unchanged). Read only in builds with the `test-hooks` feature (the
//! crate's own tests: the binary they run is built with it); elsewhere the points do nothing.
use std::sync::atomic::{AtomicU32, Ordering};

// Without the feature nothing constructs one: every point sees `None`.
#[cfg_attr(not(feature = "test-hooks"), allow(dead_code))]
enum Fault {
    Rename { pattern: String, nth: u32 },
    Frame(u32),
    Nan(u32),
    Slow(u64),
}

#[cfg(not(feature = "test-hooks"))]
fn fault() -> Option<&'static Fault> {
    None
}

#[cfg(feature = "test-hooks")]
fn fault() -> Option<&'static Fault> {
    use std::sync::OnceLock;
    static F: OnceLock<Option<Fault>> = OnceLock::new();
    F.get_or_init(|| {
        let v = std::env::var("NIMBUS_FAULT").ok()?;
        let parts: Vec<&str> = v.split(':').collect();
        match parts.as_slice() {
            ["rename", pat, n] => Some(Fault::Rename {
                pattern: pat.to_string(),
                nth: n.parse().ok()?,
            }),
            ["frame", n] => Some(Fault::Frame(n.parse().ok()?)),
            ["nan", n] => Some(Fault::Nan(n.parse().ok()?)),
            ["slow", ms] => Some(Fault::Slow(ms.parse().ok()?)),
            _ => None,
        }
    })
    .as_ref()
}

/// Called by `io::atomic` before renaming a finished temporary file onto `path`.
pub(crate) fn before_rename(path: &std::path::Path) {
    static COUNT: AtomicU32 = AtomicU32::new(0);
    if let Some(Fault::Rename { pattern, nth }) = fault() {
        if path.to_string_lossy().contains(pattern.as_str())
            && COUNT.fetch_add(1, Ordering::SeqCst) + 1 == *nth
        {
            eprintln!("NIMBUS_FAULT: aborting before renaming {}", path.display());
            std::process::abort();
        }
    }
}

/// Called by the frame loop between the substeps of a frame.
pub(crate) fn during_frame(frame: u32) {
    match fault() {
        Some(Fault::Frame(n)) if *n == frame => {
            eprintln!("NIMBUS_FAULT: aborting while simulating frame {frame}");
            std::process::abort();
        }
        Some(Fault::Slow(ms)) => std::thread::sleep(std::time::Duration::from_millis(*ms)),
        _ => {}
    }
}

/// Called by the frame loop on the state read back after a frame.
pub(crate) fn poison_state(frame: u32, state: &mut crate::ground::ParticleState) {
    if let Some(Fault::Nan(n)) = fault() {
        if *n == frame {
            if let Some(t) = state.thermo.first_mut() {
                eprintln!("NIMBUS_FAULT: temperature of particle 0 set to NaN after frame {frame}");
                t[0] = f32::NAN;
            }
        }
    }
}
