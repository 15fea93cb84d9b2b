//! The phases of a substep, in the paper's order, and their timings.
//!
//! Timings come from GPU timestamp queries where the adapter has them (every phase is one or
//! more compute passes that write a begin and an end timestamp, read back with the frame's
//! particles: no wait of their own). Without timestamps a frame records no per-phase times;
//! `Timing::HostWaits` (benchmarks) then submits and waits after every phase and times it on the
//! host, which costs the waits the normal step avoids.

/// One phase of the step (paper sections 3-5): what a stage's passes are timed under. The
/// order of the substep is `sim::step`'s; the variants follow it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Phase {
    /// Prediction of the positions (gravity, speed clamp, p* = x + v dt).
    Predict,
    /// Neighbour grid: cell keys, counting sort, cell table, arrays into cell order.
    Grid,
    /// Density constraint iterations (eqs. 1-4).
    Solve,
    /// Velocity update, vorticity confinement, XSPH viscosity.
    Velocity,
    /// Temperature smoothing and vapor mixing (section 4.1).
    Smoothing,
    /// Cloud thermodynamics (eqs. 5-11).
    Cloud,
    /// The forces that are stages of their own (`sim::forces`), after the thermodynamics.
    Forces,
    /// Shape energy, merge and split marks (section 5.2.1).
    Mark,
    /// Merges and compaction (section 5.2.2).
    Merge,
    /// Splits (section 5.2.1).
    Split,
}

/// Phases of the step.
const PHASES: usize = 10;

impl Phase {
    pub const ALL: [Phase; PHASES] = [
        Phase::Predict,
        Phase::Grid,
        Phase::Solve,
        Phase::Velocity,
        Phase::Smoothing,
        Phase::Cloud,
        Phase::Forces,
        Phase::Mark,
        Phase::Merge,
        Phase::Split,
    ];

    /// The key stats.jsonl and the benchmarks use (predict and solve are both "pbf", as they
    /// have been since the first stats files; the marks are timed with the splits).
    pub fn key(self) -> &'static str {
        match self {
            Phase::Predict | Phase::Solve => "pbf",
            Phase::Grid => "grid",
            Phase::Velocity => "velocity",
            Phase::Smoothing => "smoothing",
            Phase::Cloud => "cloud",
            Phase::Forces => "forces",
            Phase::Mark | Phase::Split => "split",
            Phase::Merge => "merge",
        }
    }

    /// A label for GPU debuggers and timestamp passes.
    pub fn label(self) -> &'static str {
        match self {
            Phase::Predict => "predict",
            Phase::Grid => "grid",
            Phase::Solve => "solve",
            Phase::Velocity => "velocity",
            Phase::Smoothing => "smoothing",
            Phase::Cloud => "cloud",
            Phase::Forces => "forces",
            Phase::Mark => "mark",
            Phase::Merge => "merge",
            Phase::Split => "split",
        }
    }
}

/// How a frame times its phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Timing {
    /// GPU timestamps where the adapter has them; otherwise no per-phase times. No extra waits.
    Timestamps,
    /// Submit and wait after every phase, timed on the host (benchmarks on adapters without
    /// timestamps; costs a wait per phase).
    HostWaits,
}

/// Milliseconds per phase summed over a frame's substeps.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseTimes {
    ms: [f64; PHASES],
    /// Which phases were timed this frame.
    ran: [bool; PHASES],
}

impl PhaseTimes {
    pub fn add(&mut self, phase: Phase, ms: f64) {
        self.ms[phase as usize] += ms;
        self.ran[phase as usize] = true;
    }

    /// Adds another frame's (or substep's) times.
    pub fn merge(&mut self, other: &PhaseTimes) {
        for p in Phase::ALL {
            if other.ran[p as usize] {
                self.add(p, other.get(p));
            }
        }
    }

    pub fn get(&self, phase: Phase) -> f64 {
        self.ms[phase as usize]
    }

    pub fn total(&self) -> f64 {
        self.ms.iter().sum()
    }

    /// The times under their stats keys (phases sharing a key summed); empty when untimed.
    /// Phases that did not run in the frame (e.g. split without adaptivity) are left out.
    pub fn by_key(&self) -> std::collections::BTreeMap<String, f64> {
        let mut out = std::collections::BTreeMap::new();
        for p in Phase::ALL {
            if self.ran[p as usize] {
                *out.entry(p.key().to_string()).or_insert(0.0) += self.get(p);
            }
        }
        out
    }
}

/// Records a substep's phases into one command encoder (one submit per substep, no wait): the
/// step opens a phase ([`Recorder::begin`]), a stage records its compute passes, each timed
/// under that phase, and the step closes it ([`Recorder::end_phase`]).
pub struct Recorder<'a> {
    ctx: &'a crate::gpu::Context,
    enc: Option<wgpu::CommandEncoder>,
    timer: Option<&'a mut crate::gpu::timing::GpuTimer<Phase>>,
    /// `Timing::HostWaits`: the frame's times and when the current phase began.
    host: Option<(&'a mut PhaseTimes, std::time::Instant)>,
    /// The phase the passes are timed under (none: untimed, as when a test runs a stage alone).
    phase: Option<Phase>,
}

impl<'a> Recorder<'a> {
    /// A recorder timing with `timer` (GPU timestamps) or, when `host` is given, by submitting
    /// and waiting after every phase.
    pub fn new(
        ctx: &'a crate::gpu::Context,
        timer: Option<&'a mut crate::gpu::timing::GpuTimer<Phase>>,
        host: Option<&'a mut PhaseTimes>,
    ) -> Self {
        Self {
            ctx,
            enc: Some(ctx.device.create_command_encoder(&Default::default())),
            timer: if host.is_some() { None } else { timer },
            host: host.map(|t| (t, std::time::Instant::now())),
            phase: None,
        }
    }

    pub fn ctx(&self) -> &'a crate::gpu::Context {
        self.ctx
    }

    fn enc_mut(&mut self) -> &mut wgpu::CommandEncoder {
        self.enc
            .as_mut()
            .expect("the recorder's encoder is open until submit")
    }

    /// Opens `phase`: the passes from here to [`Self::end_phase`] are timed under it.
    pub fn begin(&mut self, phase: Phase) {
        self.phase = Some(phase);
    }

    /// A compute pass of the open phase (timed when the adapter has timestamps).
    pub fn pass(&mut self) -> wgpu::ComputePass<'_> {
        let phase = self.phase;
        let enc = self
            .enc
            .as_mut()
            .expect("the recorder's encoder is open until submit");
        match (self.timer.as_deref_mut(), phase) {
            (Some(timer), Some(phase)) => timer.pass(enc, phase, phase.label()),
            _ => enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(phase.map_or("untimed", Phase::label)),
                timestamp_writes: None,
            }),
        }
    }

    /// The encoder, for copies and clears between passes.
    pub fn encoder(&mut self) -> &mut wgpu::CommandEncoder {
        self.enc_mut()
    }

    /// Closes the open phase: with host timing, submits what was recorded, waits, and adds the
    /// wall time to the phase; otherwise nothing.
    pub fn end_phase(&mut self) -> crate::error::Result<()> {
        let phase = self.phase.take();
        let (Some((times, since)), Some(phase)) = (self.host.as_mut(), phase) else {
            return Ok(());
        };
        let enc = self
            .enc
            .replace(self.ctx.device.create_command_encoder(&Default::default()));
        self.ctx.queue.submit(enc.map(|e| e.finish()));
        self.ctx.wait()?;
        times.add(phase, since.elapsed().as_secs_f64() * 1e3);
        *since = std::time::Instant::now();
        Ok(())
    }

    /// Submits the substep (no wait).
    pub fn submit(mut self) {
        if let Some(enc) = self.enc.take() {
            self.ctx.queue.submit([enc.finish()]);
        }
    }
}
