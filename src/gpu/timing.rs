//! Per-phase GPU timings from timestamp queries: every timed compute pass writes a begin and an
//! end timestamp; `collect` sums the spans per label. Without the feature, callers fall back to
//! CPU wall time around each submission.
use crate::error::Result;
use std::collections::BTreeMap;

/// Queries per set (wgpu's maximum); passes beyond it in one frame are not timed.
const MAX_QUERIES: u32 = 4096;

pub struct GpuTimer {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
    labels: Vec<String>,
    period_ns: f64,
}

impl GpuTimer {
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let set = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("phase timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: MAX_QUERIES,
        });
        let bytes = MAX_QUERIES as u64 * 8;
        let resolve = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamp resolve"),
            size: bytes,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamp readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Self {
            set,
            resolve,
            readback,
            labels: Vec::new(),
            period_ns: queue.get_timestamp_period() as f64,
        }
    }

    /// Begins a compute pass timed under `label` (untimed once the query set is full).
    pub fn pass<'e>(
        &mut self,
        enc: &'e mut wgpu::CommandEncoder,
        label: &str,
    ) -> wgpu::ComputePass<'e> {
        let k = self.labels.len() as u32;
        let timestamp_writes = if 2 * k + 2 <= MAX_QUERIES {
            self.labels.push(label.to_string());
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

    /// Resolves this frame's queries (call once, after the last timed pass).
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        let n = 2 * self.labels.len() as u32;
        if n == 0 {
            return;
        }
        enc.resolve_query_set(&self.set, 0..n, &self.resolve, 0);
        enc.copy_buffer_to_buffer(&self.resolve, 0, &self.readback, 0, n as u64 * 8);
    }

    /// Milliseconds per label since the last collect (blocks until the GPU is done).
    pub fn collect(&mut self, device: &wgpu::Device) -> Result<BTreeMap<String, f64>> {
        let mut out = BTreeMap::new();
        let n = 2 * self.labels.len() as u64;
        if n == 0 {
            return Ok(out);
        }
        let ts: Vec<u64> = crate::gpu::buffers::map_read(device, &self.readback, n * 8)?;
        for (k, label) in self.labels.iter().enumerate() {
            let dt = ts[2 * k + 1].saturating_sub(ts[2 * k]) as f64 * self.period_ns * 1e-6;
            *out.entry(label.clone()).or_insert(0.0) += dt;
        }
        self.labels.clear();
        Ok(out)
    }
}
