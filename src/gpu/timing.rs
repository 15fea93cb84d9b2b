//! Per-phase GPU timings from timestamp queries: every timed compute pass writes a begin and an
//! end timestamp under a phase; the frame's read-back brings the resolved timestamps home with
//! the particles (no wait of their own) and [`GpuTimer::spans`] turns them into milliseconds.
//! Adapters without timestamp queries time nothing per phase (see `sim::phase`).

/// Queries per set (wgpu's maximum); passes beyond it in one frame are not timed.
const MAX_QUERIES: u32 = 4096;

pub struct GpuTimer<P> {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    phases: Vec<P>,
    period_ns: f64,
}

impl<P: Copy> GpuTimer<P> {
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let set = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("phase timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: MAX_QUERIES,
        });
        let resolve = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamp resolve"),
            size: MAX_QUERIES as u64 * 8,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Self {
            set,
            resolve,
            phases: Vec::new(),
            period_ns: queue.get_timestamp_period() as f64,
        }
    }

    /// Begins a compute pass timed under `phase` (untimed once the query set is full).
    pub fn pass<'e>(
        &mut self,
        enc: &'e mut wgpu::CommandEncoder,
        phase: P,
        label: &str,
    ) -> wgpu::ComputePass<'e> {
        let k = self.phases.len() as u32;
        let timestamp_writes = if 2 * k + 2 <= MAX_QUERIES {
            self.phases.push(phase);
            Some(wgpu::ComputePassTimestampWrites {
                query_set: &self.set,
                beginning_of_pass_write_index: Some(2 * k),
                end_of_pass_write_index: Some(2 * k + 1),
            })
        } else {
            None
        };
        enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes,
        })
    }

    /// Resolves the frame's queries into the resolve buffer; returns its used bytes (call once,
    /// after the last timed pass, and read that many bytes of [`GpuTimer::buffer`] back).
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder) -> u64 {
        let n = 2 * self.phases.len() as u32;
        if n > 0 {
            enc.resolve_query_set(&self.set, 0..n, &self.resolve, 0);
        }
        n as u64 * 8
    }

    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.resolve
    }

    /// The milliseconds of every timed pass since the last call, from the read-back timestamps.
    pub fn spans(&mut self, timestamps: &[u64]) -> Vec<(P, f64)> {
        let out = self
            .phases
            .iter()
            .enumerate()
            .filter(|(k, _)| 2 * k + 1 < timestamps.len())
            .map(|(k, p)| {
                let ticks = timestamps[2 * k + 1].saturating_sub(timestamps[2 * k]);
                (*p, ticks as f64 * self.period_ns * 1e-6)
            })
            .collect();
        self.phases.clear();
        out
    }
}
