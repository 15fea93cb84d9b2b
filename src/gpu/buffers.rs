//! Buffer helpers: upload of typed slices, parameter blocks ([`ParamSlots`]), and read-back of
//! several buffers with one wait ([`Readback`]).
use crate::error::{Error, Result};
use wgpu::util::DeviceExt;

/// A storage buffer initialised from `data` (usable as copy source and destination).
pub fn storage_init<T: bytemuck::Pod>(
    device: &wgpu::Device,
    label: &str,
    data: &[T],
) -> wgpu::Buffer {
    let bytes: &[u8] = bytemuck::cast_slice(data);
    // wgpu refuses zero-sized bindings; keep at least 16 bytes.
    let mut padded;
    let contents = if bytes.len() < 16 {
        padded = bytes.to_vec();
        padded.resize(16, 0);
        &padded[..]
    } else {
        bytes
    };
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
    })
}

/// A range of a buffer that a stage binds as one array (a stage's scratch can be a stretch of
/// a particle array that is dead while the stage runs).
#[derive(Debug, Clone)]
pub struct Span {
    pub buffer: wgpu::Buffer,
    pub offset: u64,
    pub size: u64,
}

impl Span {
    pub fn whole(buffer: &wgpu::Buffer) -> Self {
        Self {
            buffer: buffer.clone(),
            offset: 0,
            size: buffer.size(),
        }
    }

    /// `size` bytes of `buffer` from `offset` (multiples of 256, the storage binding alignment).
    pub fn new(buffer: &wgpu::Buffer, offset: u64, size: u64) -> Self {
        assert!(offset + size <= buffer.size(), "span past the buffer's end");
        Self {
            buffer: buffer.clone(),
            offset,
            size,
        }
    }

    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        range(&self.buffer, self.offset, self.size)
    }
}

/// A binding over `size` bytes of `buffer` from `offset`.
pub fn range(buffer: &wgpu::Buffer, offset: u64, size: u64) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset,
        size: std::num::NonZeroU64::new(size),
    })
}

/// A zeroed storage buffer of `count` elements of `T`.
pub fn storage_zeroed<T>(device: &wgpu::Device, label: &str, count: usize) -> wgpu::Buffer {
    let size = (count * std::mem::size_of::<T>()).max(16) as u64;
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size.next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Copies the first `count` elements of `buffer` back to the host (one wait).
pub fn read_back<T: bytemuck::Pod>(
    ctx: &crate::gpu::Context,
    buffer: &wgpu::Buffer,
    count: usize,
) -> Result<Vec<T>> {
    let mut rb = Readback::default();
    let k = rb.add_array::<T>(buffer, count);
    let enc = ctx.device.create_command_encoder(&Default::default());
    Ok(rb.finish(ctx, enc)?.get(k))
}

/// Maps the first `size` bytes of a MAP_READ buffer, copies them out as `T`s and unmaps it
/// (waits until the GPU is done with the buffer).
pub fn map_read<T: bytemuck::Pod>(
    ctx: &crate::gpu::Context,
    buffer: &wgpu::Buffer,
    size: u64,
) -> Result<Vec<T>> {
    let slice = buffer.slice(0..size);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    ctx.wait()?;
    rx.recv()
        .map_err(|_| Error::Runtime("GPU read-back was dropped".into()))?
        .map_err(|e| Error::Runtime(format!("GPU read-back failed: {e}")))?;
    let view = slice
        .get_mapped_range()
        .map_err(|e| Error::Runtime(format!("GPU read-back mapping failed: {e:?}")))?;
    let out = bytemuck::pod_collect_to_vec::<u8, T>(&view);
    drop(view);
    buffer.unmap();
    Ok(out)
}

/// Uniform offsets must be multiples of this (WebGPU's `minUniformBufferOffsetAlignment`
/// default, which every adapter supports).
pub const SLOT_ALIGN: u64 = 256;

/// A stage's parameters: one uniform buffer of `slots` values of `T`, each on its own
/// [`SLOT_ALIGN`] boundary. One slot is a stage's parameter block; several slots are
/// per-dispatch parameters (a bind group of groups 1.. selects one with a dynamic offset) or
/// per-level parameters bound at a fixed slot. Updated with `write_buffer`, never rebuilt.
pub struct ParamSlots<T> {
    buffer: wgpu::Buffer,
    slots: u32,
    _t: std::marker::PhantomData<T>,
}

impl<T: bytemuck::Pod> ParamSlots<T> {
    pub fn new(ctx: &crate::gpu::Context, label: &str, values: &[T]) -> Self {
        let stride = Self::stride();
        let mut bytes = vec![0u8; (stride * values.len().max(1) as u64) as usize];
        for (k, v) in values.iter().enumerate() {
            let at = k * stride as usize;
            bytes[at..at + std::mem::size_of::<T>()].copy_from_slice(bytemuck::bytes_of(v));
        }
        let buffer = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: &bytes,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            });
        Self {
            buffer,
            slots: values.len().max(1) as u32,
            _t: std::marker::PhantomData,
        }
    }

    /// One parameter block.
    pub fn single(ctx: &crate::gpu::Context, label: &str, value: &T) -> Self {
        Self::new(ctx, label, std::slice::from_ref(value))
    }

    fn stride() -> u64 {
        (std::mem::size_of::<T>() as u64).next_multiple_of(SLOT_ALIGN)
    }

    /// Overwrites slot `k` (takes effect at the next submit, before its commands run).
    pub fn write(&self, ctx: &crate::gpu::Context, k: u32, value: &T) {
        assert!(k < self.slots, "parameter slot {k} of {}", self.slots);
        ctx.queue.write_buffer(
            &self.buffer,
            self.offset(k) as u64,
            bytemuck::bytes_of(value),
        );
    }

    /// The dynamic offset of slot `k`.
    pub fn offset(&self, k: u32) -> u32 {
        (k as u64 * Self::stride()) as u32
    }

    /// A binding of one slot at slot `k` (fixed), or, for a dynamic-offset group, at slot 0.
    pub fn slot(&self, k: u32) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &self.buffer,
            offset: self.offset(k) as u64,
            size: std::num::NonZeroU64::new(std::mem::size_of::<T>() as u64),
        })
    }

    pub fn size(&self) -> u64 {
        self.buffer.size()
    }
}

/// Copies of several buffer ranges into one staging buffer, read with one wait.
#[derive(Default)]
pub struct Readback<'a> {
    copies: Vec<(&'a wgpu::Buffer, u64, u64)>,
}

/// What a [`Readback`] read: part `k` is the k-th range added.
pub struct ReadbackData {
    bytes: Vec<u8>,
    parts: Vec<(usize, usize)>,
}

impl<'a> Readback<'a> {
    /// Adds `size` bytes of `buffer` from `offset` (multiples of 4); returns the part's index.
    pub fn add(&mut self, buffer: &'a wgpu::Buffer, offset: u64, size: u64) -> usize {
        self.copies.push((buffer, offset, size));
        self.copies.len() - 1
    }

    /// Adds the first `count` elements of `T` of `buffer`.
    pub fn add_array<T>(&mut self, buffer: &'a wgpu::Buffer, count: usize) -> usize {
        self.add(buffer, 0, (count * std::mem::size_of::<T>()) as u64)
    }

    /// Records the copies into `encoder`, submits it and waits once for the GPU.
    pub fn finish(
        self,
        ctx: &crate::gpu::Context,
        mut encoder: wgpu::CommandEncoder,
    ) -> Result<ReadbackData> {
        let mut parts = Vec::with_capacity(self.copies.len());
        let mut total = 0u64;
        for (_, _, size) in &self.copies {
            parts.push((total as usize, *size as usize));
            total += size.next_multiple_of(8);
        }
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: total.max(8),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        for ((buffer, offset, size), (at, _)) in self.copies.iter().zip(&parts) {
            if *size > 0 {
                encoder.copy_buffer_to_buffer(buffer, *offset, &staging, *at as u64, *size);
            }
        }
        ctx.queue.submit([encoder.finish()]);
        let bytes = map_read::<u8>(ctx, &staging, total.max(8))?;
        Ok(ReadbackData { bytes, parts })
    }
}

impl ReadbackData {
    /// Part `k` as a vector of `T`.
    pub fn get<T: bytemuck::Pod>(&self, k: usize) -> Vec<T> {
        let (at, len) = self.parts[k];
        bytemuck::pod_collect_to_vec(&self.bytes[at..at + len])
    }
}
